"""A trip whose node time wraps: the node's u32 `time_ms` passes 2**32 ms (49.7 days of uptime)
inside a landing rest. The report, the web face's trip data and `ropemon export` see the rest
whole and a time axis from 0 (ropemon.station.nodetime unwraps the node's time per node)."""
import csv

import numpy as np
import pytest

from ropemon.cli import main
from ropemon.station.nodetime import WRAP_MS, NodeClock, unwrapped_ms
from ropemon.station.protocol import Rope, decode_raw, encode_frame
from ropemon.station.report import trip_table, trips_from_store
from ropemon.station.store import Store
from ropemon.station.web import logread

AREA = 0.0314
NODE = 3
BOOT = 7
RX0 = 1_760_000_000.0              # host time of the first frame
TOP = [46_300, 46_400, 46_200, 46_500]        # N at the pithead (the rest it leaves)
BOTTOM = [30_000, 30_100, 29_900, 30_000]     # N at the bottom on arrival
UNLOADED = [20_000, 20_100, 19_900, 20_000]   # N at the bottom from 12 s after arrival


def wound(db, wrap_at_s, seq0=1000):
    """Write one wind into `db`: 20 s at the pithead, 100 s down at 9 m/s, 30 s at the bottom
    (unloaded 12 s after arriving), 10 frames/s; the node's time wraps `wrap_at_s` after the
    first frame. Returns the frames' (time_ms, seq)."""
    out = []
    with Store(db) as st:
        for k in range(1500):
            t = k * 0.1
            moving = 20.0 <= t < 120.0
            depth = 810 * min(max((t - 20.0) / 100.0, 0.0), 1.0)
            comp = TOP if t < 20.0 else BOTTOM if t < 132.0 else UNLOADED
            raw_kpa = [int(0.83 * c / AREA / 1000) for c in comp]
            time_ms = (int(round((t - wrap_at_s) * 1000))) % WRAP_MS
            seq = (BOOT << 20) | (seq0 + k)
            raw, _ = encode_frame(node=NODE, seq=seq, time_ms=time_ms, depth_mm=int(depth * 1000),
                                  speed_mm_s=9000 if moving else 0, battery_mv=12000,
                                  ropes=[Rope(c // 10, c // 10 - 5, c // 10 + 5, p) for c, p in zip(comp, raw_kpa)])
            st.add_frame("pithead", decode_raw(raw), RX0 + t)
            out.append((time_ms, seq))
    return out


# where the node's time wraps, s after the first frame: 3 s into the arrival rest (inside its
# averaged window, 1 .. 6 s after arriving at 120 s); in the rest the cage leaves at 20 s,
# 10 s before leaving (before its averaged window, the last 5 s) and 2 s before (inside it)
WRAPS = {"arrival": 123.0, "departure-early": 10.0, "departure-late": 18.0}


@pytest.mark.parametrize("where", sorted(WRAPS))
def test_report_sees_both_rests_whole_across_a_wrap(tmp_path, where):
    db = tmp_path / "log.db"
    sent = wound(db, WRAPS[where])
    assert any(b < a for (a, _), (b, _) in zip(sent, sent[1:]))      # the node's time did wrap
    with Store(db, readonly=True) as st:
        (trip,) = trips_from_store(st, [AREA] * 4, 810)
    assert trip.direction == "pithead -> bottom"
    assert trip.start.comp_n == pytest.approx(TOP) and trip.end.comp_n == pytest.approx(BOTTOM)
    assert trip.start.frames == 50 and trip.end.frames == 50
    t = trip.frames.t_s
    assert np.all(np.diff(t) == pytest.approx(0.1))
    # the rests' node times: the arrival figure 1 .. 6 s after arriving (120 s), the departure's
    # the last 5 s before leaving (20 s); both past the wrap or before it, by the same count
    assert trip.end.t_s - t[0] == pytest.approx(123.45, abs=0.06)
    assert trip.start.t_s - t[0] == pytest.approx(17.45, abs=0.06)
    text = trip_table(trip, None)
    assert "pithead (left)" in text and "bottom (arrived)" in text
    assert f"{t[0]:.1f} .. {t[-1]:.1f} s" in text and t[-1] - t[0] == pytest.approx(149.9)


def test_web_trip_page_across_a_wrap_has_its_rests_and_an_axis_from_0(tmp_path):
    db = tmp_path / "log.db"
    wound(db, WRAPS["arrival"])
    with Store(db, readonly=True) as st:
        (tr,) = st.trips()
        detail = logread.trip_detail(st, tr.id, [AREA] * 4, 810.0)
    report = detail["report"]
    assert report.end is not None and report.end.comp_n == pytest.approx(BOTTOM)
    assert report.start is not None and report.start.comp_n == pytest.approx(TOP)
    table = logread.rest_rows(report)
    assert table["columns"] == ["pithead (left)", "bottom (arrived)"]
    assert table["rows"][-1]["cells"][1][1] == pytest.approx(sum(BOTTOM) / 1000, abs=0.1)
    series = logread.trip_series(detail)
    t = series["t"]
    assert t[0] == 0.0 and min(t) == 0.0 and max(t) == pytest.approx(149.9)
    assert all(b > a for a, b in zip(t, t[1:]))
    rows = list(csv.DictReader(logread.trip_csv(detail).splitlines()))
    node_t = [float(r["node_time_s"]) for r in rows]
    assert all(b > a for a, b in zip(node_t, node_t[1:]))


def test_export_adds_the_unwrapped_node_time(tmp_path, capsys):
    db = tmp_path / "log.db"
    sent = wound(db, WRAPS["arrival"])
    assert main(["export", str(db), "--out", str(tmp_path / "csv")]) == 0
    rows = list(csv.DictReader((tmp_path / "csv" / "frames.csv").open()))
    assert [int(r["time_ms"]) for r in rows] == [tm for tm, _ in sent]         # as the node sent it
    node_ms = [int(r["node_time_ms"]) for r in rows]
    assert node_ms[0] == sent[0][0] and all(b - a == 100 for a, b in zip(node_ms, node_ms[1:]))
    assert node_ms[-1] > WRAP_MS
    with (tmp_path / "csv" / "frames.csv").open() as fh:
        head = next(csv.reader(fh))
    assert head[-1] == "node_time_ms" and head.index("stroke_mask") < head.index("node_time_ms")


# -- the clock itself ------------------------------------------------------------------------


class F:
    def __init__(self, node, boot, count, time_ms):
        self.node, self.seq, self.time_ms = node, (boot << 20) | count, time_ms


def test_a_wrap_adds_2_32_and_a_restart_starts_again():
    c = NodeClock()
    assert c.ms(F(1, 4, 10, WRAP_MS - 150)) == WRAP_MS - 150
    assert c.ms(F(1, 4, 11, WRAP_MS - 50)) == WRAP_MS - 50
    assert c.ms(F(1, 4, 12, 50)) == WRAP_MS + 50                    # wrapped
    assert c.ms(F(2, 0, 0, 1000)) == 1000                           # another node: its own
    assert c.ms(F(1, 4, 13, 20)) == WRAP_MS + 20                    # a little out of order
    assert c.ms(F(1, 5, 0, 150)) == 150                             # boot + 1 at time 0.15 s: a restart
    assert c.ms(F(1, 5, 1, 250)) == 250


def test_the_frame_count_running_over_is_no_restart():
    """Every 2**20 frames the node bumps its boot counter while running on (docs/protocol.md):
    its time follows on, the wraps counted so far are kept."""
    c = NodeClock()
    count = (1 << 20) - 3
    ms = [c.ms(F(1, 9, count, WRAP_MS - 200)), c.ms(F(1, 9, count + 1, WRAP_MS - 100)),
          c.ms(F(1, 9, count + 2, 0)), c.ms(F(1, 10, 0, 100)), c.ms(F(1, 10, 2, 300))]
    assert ms == [WRAP_MS - 200, WRAP_MS - 100, WRAP_MS, WRAP_MS + 100, WRAP_MS + 300]
    # a restart: the next boot, count 0, the time from 0 again (not a wrap, though it went back)
    assert c.ms(F(1, 11, 0, 90)) == 90
    c.ms(F(1, 11, (1 << 20) - 2, 5_000_000))
    assert c.ms(F(1, 12, 0, 90)) == 90          # the count near its end but the time went back
    assert unwrapped_ms([F(1, 0, k, (k * 100 + WRAP_MS - 250) % WRAP_MS) for k in range(5)]) == \
        [WRAP_MS - 250 + 100 * k for k in range(5)]
