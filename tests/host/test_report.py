"""`ropemon report`: per-trip table (raw and compensated at the pithead and the bottom,
sum against the theoretical load) and PNG plots, from a log written through the Store."""
import numpy as np
import pytest

from ropemon.cli import main
from ropemon.station.protocol import L, Rope, decode_raw, encode_frame
from ropemon.station.report import HoistLoad, trip_table, trips_from_store
from ropemon.station.store import Store

AREA = 0.0314
LOAD = HoistLoad(cage_kg=8180, tail_ropes=2, tail_kg_per_m=6.62, shaft_m=810)


def wind(store, t0_s=0.0, seq0=0, down=True, pos_01mm=None):
    """10 s rest, a 100 s wind at 9 m/s, 10 s rest; tensions per phase known; with `pos_01mm`
    (per rope) the pistons stand there throughout."""
    seq = seq0
    top = [46_300, 46_400, 46_200, 46_500]          # N, compensated at the pithead
    bottom = [30_000, 30_100, 29_900, 30_000]
    for k in range(1200):
        t = k * 0.1
        moving = 10.0 <= t < 110.0
        frac = min(max((t - 10.0) / 100.0, 0.0), 1.0)
        frac = frac if down else 1 - frac
        depth_m = 810 * frac
        comp = top if frac < 0.5 else bottom
        raw_kpa = [int(0.83 * c / AREA / 1000) for c in comp]   # raw reads 17 % low
        ropes = [Rope(c // 10, c // 10 - 5, c // 10 + 5, p, *([] if pos_01mm is None else [pos_01mm[i]]))
                 for i, (c, p) in enumerate(zip(comp, raw_kpa))]
        raw, _ = encode_frame(node=3, seq=seq, time_ms=int((t0_s + t) * 1000), ropes=ropes,
                              depth_mm=int(depth_m * 1000), speed_mm_s=(9000 if down else -9000) if moving else 0,
                              battery_mv=3900)
        store.add_frame("pithead", decode_raw(raw), t0_s + t)
        seq += 1
    return seq


def test_two_winds_give_two_trips_with_the_papers_table(tmp_path):
    db = tmp_path / "log.db"
    with Store(db) as st:
        seq = wind(st, 0.0, 0, down=True)
        wind(st, 200.0, seq, down=False)
    with Store(db) as st:
        trips = trips_from_store(st, [AREA] * 4, 810)
    assert [t.direction for t in trips] == ["pithead -> bottom", "bottom -> pithead"]
    pit = trips[0].rest_at("pithead")
    assert pit.comp_n == pytest.approx([46_300, 46_400, 46_200, 46_500])
    assert pit.raw_n.sum() == pytest.approx(0.83 * 185_400, rel=2e-3)
    text = trip_table(trips[0], LOAD)
    lines = {ln.split()[0]: ln.split() for ln in text.splitlines()[1:] if ln.split()}
    raw_sum_kn = sum(int(0.83 * c / AREA / 1000) for c in (46_300, 46_400, 46_200, 46_500)) * AREA
    assert lines["sum"][1:3] == [f"{raw_sum_kn:.1f}", "185.4"]     # pithead raw, compensated
    th = LOAD.load_n(0)                                            # (8180 + 2 x 6.62 x 810) x 9.81
    assert lines["theoretical"][1] == f"{th / 1000:.1f}"
    assert lines["error"][2:4] == [f"{(raw_sum_kn * 1000 - th) / th * 100:+.1f}", f"{(185_400 - th) / th * 100:+.1f}"]
    assert float(lines["error"][2]) == pytest.approx(-17.0, abs=0.2)


def test_theoretical_load_uses_the_payload_at_the_time_of_each_rest(tmp_path):
    """With a log of loading (payload as a function of node time), each rest's theoretical
    load takes the payload in the cage while that rest was averaged, not at another time."""
    db = tmp_path / "log.db"
    with Store(db) as st:
        wind(st, 0.0, 0, down=True)
    with Store(db) as st:
        trip = trips_from_store(st, [AREA] * 4, 810)[0]
    t_left, t_arrived = trip.start.t_s, trip.end.t_s
    assert t_left < t_arrived
    text = trip_table(trip, LOAD, lambda t: 0.0 if t < (t_left + t_arrived) / 2 else 5000.0)
    th = {ln.split()[0]: ln.split() for ln in text.splitlines()[1:] if ln.split()}["theoretical"]
    assert th[1:] == [f"{LOAD.load_n(trip.start.depth_m) / 1000:.1f}",
                      f"{LOAD.load_n(trip.end.depth_m, 5000.0) / 1000:.1f}"]


def test_report_command_writes_pngs_and_text(tmp_path, capsys):
    db = tmp_path / "log.db"
    with Store(db) as st:
        wind(st)
    out = tmp_path / "rep"
    assert main(["report", str(db), "--out", str(out), "--area-m2", str(AREA)]) == 0
    printed = capsys.readouterr().out
    assert "trip 1 (node 3): pithead -> bottom" in printed
    png = out / "trip001-node3.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert (out / "report.txt").read_text().startswith("trip 1")


def test_report_refuses_missing_db_and_missing_area(tmp_path, capsys):
    assert main(["report", str(tmp_path / "nope.db"), "--area-m2", "0.03"]) == 2
    assert "no such file" in capsys.readouterr().err
    db = tmp_path / "log.db"
    Store(db).close()
    assert main(["report", str(db)]) == 2
    assert "piston area" in capsys.readouterr().err


def test_theoretical_load_matches_the_paper():
    assert LOAD.load_n(0.0) == pytest.approx(185.4e3, rel=1e-3)
    assert LOAD.load_n(810.0, payload_kg=10_000) == pytest.approx((8180 + 10_000) * 9.81)


def test_rest_figure_is_taken_on_arrival_not_after_unloading(tmp_path):
    """Loading/unloading later in a rest must not blur the arrival figure."""
    db = tmp_path / "log.db"
    with Store(db) as st:
        seq = 0
        for k in range(900):
            t = k * 0.1
            moving = 5.0 <= t < 55.0
            depth = 810 * min(max((t - 5.0) / 50.0, 0.0), 1.0)
            comp = 60_000 if t < 70.0 else 40_000       # unloaded 15 s after arrival
            raw, _ = encode_frame(node=1, seq=seq, time_ms=int(t * 1000), depth_mm=int(depth * 1000),
                                  speed_mm_s=16000 if moving else 0, battery_mv=3900,
                                  ropes=[Rope(comp // 10, comp // 10, comp // 10, 1000)] * 4)
            st.add_frame("pithead", decode_raw(raw), t)
            seq += 1
    with Store(db) as st:
        (trip,) = trips_from_store(st, [AREA] * 4, 810)
    assert trip.direction == "pithead -> bottom"
    assert trip.end.comp_n == pytest.approx([60_000] * 4)
    assert trip.end.frames == 50


def test_creep_while_loading_is_not_a_trip(tmp_path):
    db = tmp_path / "log.db"
    with Store(db) as st:
        seq = 0
        for k in range(300):          # 30 s at the bottom, rope stretch creeps the cage 2 cm
            t = k * 0.1
            raw, _ = encode_frame(node=1, seq=seq, time_ms=int(t * 1000), depth_mm=810_000 + (k // 10),
                                  speed_mm_s=150 if 100 <= k < 105 else 0, battery_mv=3900,
                                  ropes=[Rope(3000, 3000, 3000, 1000)] * 4)
            st.add_frame("pithead", decode_raw(raw), t)
            seq += 1
        assert st.trips() == []        # half a second of pulses: not sustained motion
        assert trips_from_store(st, [AREA] * 4, 810) == []


def test_a_failed_sensor_rope_is_left_out_not_averaged_as_minus_32768(tmp_path):
    db = tmp_path / "log.db"
    with Store(db) as st:
        for k in range(900):
            t = k * 0.1
            moving = 5.0 <= t < 55.0
            depth = 810 * min(max((t - 5.0) / 50.0, 0.0), 1.0)
            r2 = Rope(-32768, -32768, -32768, 0xFFFF) if k % 2 else Rope(5000, 5000, 5000, 1500)
            raw, _ = encode_frame(node=1, seq=k, time_ms=int(t * 1000), depth_mm=int(depth * 1000),
                                  speed_mm_s=16000 if moving else 0, battery_mv=3900,
                                  ropes=[Rope(5000, 5000, 5000, 1500), r2, Rope(5000, 5000, 5000, 1500),
                                         Rope(5000, 5000, 5000, 1500)])
            st.add_frame("pithead", decode_raw(raw), t)
    with Store(db) as st:
        (trip,) = trips_from_store(st, [AREA] * 4, 810)
    assert trip.end.comp_n == pytest.approx([50_000] * 4)
    assert trip.end.raw_n[1] == pytest.approx(1500e3 * AREA)


def test_a_loadings_rope_stretch_does_not_start_the_trip(tmp_path):
    """Loading at the bottom stretches the ropes: a frame with one encoder pulse every half
    second for 30 s, the cage otherwise at rest. The trip starts when the wind does, so its
    bottom figure is the loaded cage's just before it left, not the empty cage's."""
    db = tmp_path / "log.db"
    empty, loaded = 30_000, 37_000
    with Store(db) as st:
        depth_mm = 810_000
        for k in range(1600):
            t = k * 0.1
            loading = 10.0 <= t < 40.0
            pulse = loading and k % 5 == 0                     # 10 mm down: 100 mm/s in that frame
            winding = 46.0 <= t < 146.0
            speed = 100 if pulse else (-8100 if winding else 0)
            depth_mm += speed // 10
            comp = empty + (loaded - empty) * min(max((t - 10.0) / 30.0, 0.0), 1.0)
            comp = int(comp) if not winding and t < 146.0 else int(loaded * 0.98)
            raw, _ = encode_frame(node=1, seq=k, time_ms=int(t * 1000), depth_mm=depth_mm, speed_mm_s=speed,
                                  battery_mv=3900, ropes=[Rope(comp // 10, comp // 10, comp // 10, 1000)] * 4)
            st.add_frame("pithead", decode_raw(raw), t)
        (stored,) = st.trips()
        assert stored.start_time == pytest.approx(46.0)
        (trip,) = trips_from_store(st, [AREA] * 4, 810)
    assert trip.direction == "bottom -> pithead"
    assert trip.start.comp_n == pytest.approx([loaded] * 4)
    assert trip.start.t_s > 40_000 / 1000


def creeping_winds(db, trips=8):
    """`trips` winds, down then up; the pistons' rest positions creep per wind: rope 1 +1 mm,
    rope 2 not at all, rope 3 -0.5 mm, rope 4 without a position (its channel failed)."""
    with Store(db) as st:
        seq = 0
        for k in range(trips):
            seq = wind(st, 200.0 * k, seq, down=k % 2 == 0, pos_01mm=[10 * k, 0, -5 * k, L.POS_ABSENT])


def test_rest_positions_per_trip_and_the_rope_adjustment_forecast(tmp_path):
    from ropemon.station.report import adjust_table, rest_positions
    db = tmp_path / "log.db"
    creeping_winds(db)
    with Store(db, readonly=True) as st:
        trips = trips_from_store(st, [AREA] * 4, 810)
    assert len(trips) == 8
    assert trips[2].end.pos_m[:3] == pytest.approx([0.002, 0.0, -0.001])
    text = trip_table(trips[2], LOAD)
    rows = [ln.split() for ln in text.splitlines()[text.splitlines().index(
        next(ln for ln in text.splitlines() if ln.split()[:2] == ["piston", "mm"])) + 1:]]
    assert rows == [["rope", "1", "+2.0", "+2.0"], ["rope", "2", "+0.0", "+0.0"],   # where it left, arrived
                    ["rope", "3", "-1.0", "-1.0"], ["rope", "4", "--", "--"]]
    pit = rest_positions(trips, "pithead")
    assert pit[0] == [None] * 4 and pit[1][:3] == pytest.approx([0.001, 0.0, -0.0005])
    fc = adjust_table(trips, [0.1] * 4, 0.01).splitlines()
    assert fc[0].startswith("rope adjustment (node 3): the pistons' rest positions across 8 trips")
    # +1 mm per wind, at +7 mm after the 8th wind: (40 - 7) / 1 winds before the extended end's margin
    assert fc[1] == "  at the pithead: rope 1: +1.00 mm/wind, at +7.0 mm, 33 winds left before the extended end's margin"
    assert fc[2].split(": ", 1)[1] == "+0.00 mm/wind, at +0.0 mm, no end in sight"
    assert fc[3].endswith("-0.50 mm/wind, at -3.5 mm, 73 winds left before the retracted end's margin")
    assert fc[4].endswith("rope 4: no position at its rests")
    assert fc[5].startswith("  at the bottom: rope 1: +1.00 mm/wind, at +7.0 mm, 33 winds left")
    assert "give --config" in adjust_table(trips, None, None)


def test_report_command_prints_the_forecast_with_the_stroke_from_the_config(tmp_path, capsys):
    import json
    from ropemon.commission.nodejson import example_physical, make_node_json
    db = tmp_path / "log.db"
    creeping_winds(db, trips=6)
    cfg = tmp_path / "node.json"
    phys = example_physical()
    cfg.write_text(json.dumps(make_node_json(phys, node_id=3, key=bytes(16))))
    cfg.chmod(0o600)
    assert main(["report", str(db), "--out", str(tmp_path / "rep"), "--config", str(cfg)]) == 0
    out = capsys.readouterr().out
    stroke_mm = phys["stroke_m"][0] * 1000
    assert "piston mm" in out and f"(stroke {stroke_mm:g} mm, margin " in out
    assert "at the pithead: rope 1: +1.00 mm/wind, at +5.0 mm" in out
    assert "rope adjustment (node 3)" in (tmp_path / "rep" / "report.txt").read_text()
