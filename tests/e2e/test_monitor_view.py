"""The live dashboard drawn at 80x24 (an ssh terminal in the hoist room)."""
import dataclasses
import io
import math

import pytest
from rich.console import Console

from ropemon.station.monitor import MonitorView, sparkline, stroke_gauge
from ropemon.station.pipeline import AlarmState
from ropemon.station.protocol import L, Rope, decode_raw, encode_frame
from ropemon.station.nodefigures import NodeFigures

AREA = 0.0314
SITE = NodeFigures([AREA] * 4, rated_rope_tension_n=80_000, rated_load_n=320_000,
                   imbalance_frac=0.10, battery_low_v=3.4)


def frame(seq, dan=(4600, 4600, 4600, 4600), raw_kpa=1300, battery_mv=3710, status=0, ropes=True):
    rs = [Rope(d, max(d - 100, -32768), min(d + 100, 32767), raw_kpa) for d in dan] if ropes else []
    raw, _ = encode_frame(node=1, seq=seq, time_ms=seq * 100, ropes=rs, depth_mm=412_300,
                          speed_mm_s=-9_800, battery_mv=battery_mv, status=status)
    return decode_raw(raw)


def draw(view, now_s=10.0):
    c = Console(width=80, height=24, record=True, file=io.StringIO(), color_system=None)
    c.print(view.render(now_s))
    text = c.export_text()
    lines = text.splitlines()
    assert len(lines) <= 24, text
    assert max(len(line) for line in lines) <= 80, text
    return text


def rows(text):
    return {ln.split()[0]: ln.split() for ln in text.splitlines() if ln.split()}


def test_waiting_screen_fits():
    assert "waiting for frames" in draw(MonitorView(SITE))


def test_each_rope_compensated_raw_deviation_and_total():
    v = MonitorView(SITE)
    v.show_frame(frame(1, dan=(4600, 4400, 5200, 4600), raw_kpa=1300), 9.9)
    r = rows(draw(v))
    mean = (46 + 44 + 52 + 46) / 4
    assert r["3"][1] == "52.0"                                   # compensated kN
    assert r["3"][2] == f"{1300e3 * AREA / 1000:.1f}"            # raw = p x A
    assert r["3"][3] == f"{(52 - mean) / mean * 100:+.1f}"       # deviation from the mean
    assert r["sum"][1] == "188.0" and r["sum"][2] == f"{4 * 1300e3 * AREA / 1000:.1f}"
    assert "59 %" in " ".join(r["sum"])                          # 188 of 320 kN rated


class Status:
    """A hoist's standing status as the alarm engine gives it (what the view reads of it)."""

    def __init__(self, text, hidden_frac=None, rope_n=None, limit=0.10, notes=()):
        self.text, self.hidden_frac, self.rope_n, self.limit, self.notes = text, hidden_frac, rope_n, limit, notes


def test_worst_case_screen_still_fits_80x24():
    v = MonitorView(dataclasses.replace(SITE, stroke_m=[0.1] * 4, stroke_margin_m=0.01))
    for k in range(40):
        rs = [Rope(d, d, d, 65535, p) for d, p in zip((32000, -32000, 32767, 0), (-32767, 32767, L.POS_ABSENT, 0))]
        raw, _ = encode_frame(node=1, seq=k, ropes=rs, battery_mv=0, status=0x7FF, fault_mask=0x8F,
                              stroke_mask=0xFF)
        v.show_frame(decode_raw(raw), 9.0)
    v.link_rows = [("pithead", "97.1 % crc 3 bad 1"), ("mid-shaft", "45.0 % crc 12 bad 0")]
    v.merge_text = "frames 123456  lost 12  dup 600"
    v.on_alarms(AlarmState(9.0, (), {}, (), {1: Status("x" * 200)}))
    v.alarm_rows = [(f"alarm {i} " + "x" * 90, i % 2 == 0) for i in range(9)]
    text = draw(v, now_s=99.0)
    assert "and 4 more" in text and "last frame" in text and " hoist: xxx" in text
    assert "FAULT: displacement" in text                  # rope 4's channel (fault_mask bit 7)


def test_stroke_gauge_cells():
    assert stroke_gauge(0.0, 0.1, 0.01) == "[:···█···:]"     # mid-stroke; one cell of margin each end
    assert stroke_gauge(-0.05, 0.1, 0.01) == "[█·······:]"   # on the retracted end stop
    assert stroke_gauge(0.0499, 0.1, 0.01) == "[:·······█]"  # at the extended one (x > 0: pulled out)
    assert stroke_gauge(0.2, 0.1, 0.01) == "[:·······█]"     # beyond the stroke: held at the stop
    assert stroke_gauge(None, 0.1, 0.03) == "[:::···:::]"    # no position; a wider margin
    assert stroke_gauge(0.0, None, 0.01) == "" and stroke_gauge(0.0, 0.1, None) == "[····█····]"


def v3(seq, pos, stroke_mask=0, fault_mask=0):
    rs = [Rope(4600, 4500, 4700, 1300, p) for p in pos]
    raw, _ = encode_frame(node=1, seq=seq, time_ms=seq * 100, ropes=rs, depth_mm=412_300, battery_mv=3710,
                          stroke_mask=stroke_mask, fault_mask=fault_mask,
                          status=L.ST_STROKE_LIMIT if stroke_mask else 0)
    return decode_raw(raw)


def test_a_stroke_gauge_per_rope_follows_the_piston_and_marks_the_margin():
    v = MonitorView(dataclasses.replace(SITE, stroke_m=[0.1] * 4, stroke_margin_m=0.01))
    v.show_frame(v3(1, (0, 455, -300, L.POS_ABSENT)), 9.9)
    text = draw(v)
    r = rows(text)
    assert "piston mm" in text and "min..max" not in text   # the gauge takes the window's min..max
    assert r["1"][4:6] == ["[:···█···:]", "+0.0"]
    assert r["2"][4:6] == ["[:·······█]", "+45.5"]           # in the extended end's margin
    assert r["3"][4:6] == ["[:█······:]", "-30.0"]
    assert r["4"][4:6] == ["no", "position"]
    f = v.last
    assert v._gauge(f, 1).style == "bold red" and v._gauge(f, 0).style == "" and v._gauge(f, 2).style == ""
    v.show_frame(v3(2, (200, 455, -300, 0), stroke_mask=1 << 2), 10.0)   # rope 1 moves; rope 3 touched its margin
    text = draw(v, 10.0)
    r = rows(text)
    assert r["1"][4:6] == ["[:·····█·:]", "+20.0"]
    assert v._gauge(v.last, 2).style == "bold red"          # the node saw it within the margin in the window
    assert "stroke_limit" in text
    v.show_frame(v3(3, (200, 455, -300, 0), fault_mask=1 << 5), 10.1)    # rope 2's displacement channel fails
    assert rows(draw(v, 10.1))["2"][4:6] == ["FAULT:", "displacement"]


def test_version_2_frames_keep_the_window_min_max_and_no_gauge():
    v = MonitorView(dataclasses.replace(SITE, stroke_m=[0.1] * 4, stroke_margin_m=0.01))
    rs = [Rope(4600, 4500, 4700, 1300)] * 4
    v.show_frame(decode_raw(encode_frame(node=1, seq=1, ropes=rs, version=2)[0]), 9.9)
    text = draw(v)
    assert "min..max" in text and "piston" not in text and rows(text)["1"][4] == "45.0..47.0"


def test_the_hoist_status_line_is_status_not_an_alarm():
    v = MonitorView(SITE)
    v.show_frame(frame(1), 9.9)
    v.on_alarms(AlarmState(9.9, (), {}, (), {1: Status("seals can hide 16.2 % at 46 kN per rope")}))
    text = draw(v)
    assert " hoist: seals can hide 16.2 % at 46 kN per rope" in text and "alarms: none" in text
    v.on_alarms(AlarmState(9.9, (), {}, (), {1: Status("long", 0.162, 46_400.0)}))
    assert " hoist: seals can hide 16.2 % at 46.4 kN/rope, beyond the 10 % limit\n" in draw(v)
    v.on_alarms(AlarmState(9.9, (), {}, (), {1: Status("long", 0.052, 46_400.0, notes=("oil loss not watched",))}))
    line = next(ln for ln in draw(v).splitlines() if ln.startswith(" hoist: "))
    assert line == " hoist: seals can hide 5.2 % at 46.4 kN/rope, within the 10 % limit; oil loss …"   # 79 wide
    v.on_alarms(AlarmState(9.9, (), {}, (), {}))             # no band: no line
    assert "hoist:" not in draw(v)


def test_trend_and_alarms_and_stale_link_are_shown():
    v = MonitorView(SITE)
    for k in range(30):
        v.show_frame(frame(k, dan=(4600 + int(200 * math.sin(k / 3)), 4600, 4600, 4600)), 1.0 + k * 0.1)
    v.alarm_rows = [("deviation rope 3 +12.1 %", False), ("battery low 3.30 V", True)]
    text = draw(v, now_s=10.0)
    line1 = rows(text)["1"]
    assert len(set(line1[-1])) > 3                               # a moving rope has a shaped sparkline
    assert set(rows(text)["2"][-1]) <= set("▁▂▃▄▅▆▇█") and len(set(rows(text)["2"][-1])) == 1
    assert "! NEW deviation rope 3" in text and "ack battery low" in text
    assert "6.1 s ago" in text                                   # last frame at 3.9 s, now 10 s


def test_status_frame_says_not_compensating():
    v = MonitorView(SITE)
    v.show_frame(frame(1, ropes=False, status=0x0004), 1.0)
    text = draw(v)
    assert "not compensating" in text and "config_fault" in text


def test_sparkline_scales():
    assert sparkline([0, 5, 10], 0, 10) == "▁▅█"
    assert sparkline([3, 3], 3, 3) == "▁▁"


def test_failed_sensor_rope_is_shown_as_fault_and_left_out_of_the_sum():
    v = MonitorView(SITE)
    v.show_frame(frame(1, dan=(4600, -32768, 4600, 4600)), 1.0)
    r = rows(draw(v))
    assert r["2"][1] == "FAULT"
    assert r["part"][1] == "138.0" and "PARTIAL SUM: rope 2 missing" in " ".join(r["part"])
    assert r["1"][3] == "+0.0"


def test_two_cage_nodes_one_shown_the_other_summarised_and_switchable():
    v = MonitorView(SITE)
    v.show_frame(frame(1, dan=(4600,) * 4), 1.0)
    raw, _ = encode_frame(node=2, seq=1, time_ms=100, ropes=[Rope(3000, 3000, 3000, 900)] * 4,
                          depth_mm=800_000, battery_mv=3800)
    v.show_frame(decode_raw(raw), 1.5)
    text = draw(v, now_s=2.0)
    assert "node 1 seq 1" in text and "node 2: 120.0 kN, 800 m, 0.5 s ago" in text and "n: next node" in text
    v.next_node()
    text = draw(v, now_s=2.0)
    assert "node 2 seq 1" in text and "node 1: 184.0 kN" in text
    assert rows(text)["sum"][1] == "120.0"


@pytest.mark.parametrize("legacy", [False, True])
def test_band_beside_the_deviation_the_hoist_status_and_legacy_deviation_possible(legacy):
    """With the seal's friction lines each rope shows its deviation's band, and the hoist's
    standing status says what imbalance the seals can hide. A rope whose estimate flipped while
    its pressure barely moved reads +6 % but may reach 10 %: no alarm (the seals' reach is the
    hoist's figure, shown as status); only the legacy station (`legacy_deviation_possible`, the
    evaluation's baseline) raises DEVIATION POSSIBLE for it, in the warning colour."""
    from ropemon.station.nodefigures import alarm_settings
    from e2e_rig import Rig
    from ropemon.station.uncertainty import BandParams

    phys = {"ropes": 4, "cylinder_area_m2": [0.01] * 4,
            "friction": {"Fs": {"intercept": 0.0, "slope": 600.0}, "Fc": {"intercept": 0.0, "slope": 400.0},
                         "residual": 50.0}, "band_anchor": True, "band_margin": 0.10}
    site = NodeFigures([0.01] * 4, rated_rope_tension_n=80_000, imbalance_frac=0.10,
                       band=BandParams.from_physical(phys))
    clk = [0.0]
    settings = dataclasses.replace(alarm_settings(site), legacy_deviation_possible=legacy)
    s = Rig(None, settings, site, lambda: clk[0])

    def send(seq, ropes):          # (tension daN, friction estimate N) per rope
        rs = [Rope(t, t, t, round((t * 10 - f) / 10)) for t, f in ropes]
        clk[0] = seq * 0.1
        s.feed("pithead", encode_frame(node=1, seq=seq, time_ms=seq * 100, ropes=rs, battery_mv=3900)[1])

    for k in range(11):            # a pressure rise drives every estimate to +2 kN: anchored
        send(k, [(4200 + 100 * k, 2000.0)] * 4)
    for k in range(11, 20):        # at rest, every rope on its anchor
        send(k, [(5200, 2000.0)] * 4)
    s.tick()
    text = draw(s.view, clk[0])
    r = rows(text)
    assert r["1"][3:5] == ["+0.0", "+-0.3"]    # deviation % and its band: 100 N floors on 52 kN ropes
    assert not s.alarms.active()
    hidden = s.alarms.hoist_status(1)
    assert hidden is not None and hidden.hidden_frac > 0
    assert f" hoist: seals can hide {hidden.hidden_frac * 100:.1f} % at 52.0 kN/rope, " in text
    assert "alarms: none" in text
    flipped = round(5200 * 3 * 1.06 / 2.94)
    for k in range(20, 40):
        send(k, [(5200, 2000.0)] * 3 + [(flipped, -2000.0)])
    s.tick()
    text = draw(s.view, clk[0])
    r = rows(text)
    assert r["4"][3] == "+6.0" and float(r["4"][4].removeprefix("+-")) >= 4.0
    if not legacy:
        assert "DEVIATION POSSIBLE" not in text and "alarms: none" in text and " hoist: " in text
        return
    assert "DEVIATION POSSIBLE rope 4: +6.0 % +-" in text and "from mean: may reach 10 %" in text
    alarms = s.view._alarms()
    assert any(sp.style == "bold yellow" for sp in alarms.spans)
    assert not any(sp.style == "bold red" for sp in alarms.spans)

def test_the_rope_adjustment_advisory_is_a_warning_in_yellow():
    v = MonitorView(SITE)
    v.show_frame(frame(1), 9.9)
    v.alarm_rows = [("ROPE ADJUST rope 2: rest position +0.80 mm/wind, 12 winds left", False)]
    spans = {sp.style for sp in v._alarms().spans}
    assert "bold yellow reverse" in spans and "bold yellow" in spans and "bold red" not in spans
    v.alarm_rows.insert(0, ("STROKE LIMIT rope 3: rope 3 piston at its retracted end", False))
    spans = {sp.style for sp in v._alarms().spans}
    assert "bold red reverse" in spans and "bold red" in spans and "bold yellow" in spans


def test_a_held_back_rope_is_marked_and_explained_within_80x24():
    """Status bits 11-14 (the node held a rope's compensation back at rest): the rope's
    tension carries a `*` and one line under the table names the ropes and why; the node's
    flags line does not repeat it. Without the bits, neither."""
    v = MonitorView(SITE)
    v.show_frame(frame(1, status=(0b0110 << L.ST_HELD_BACK_SHIFT)), 9.9)
    text = draw(v)
    r = rows(text)
    assert r["2"][1] == "46.0*" and r["3"][1] == "46.0*" and r["1"][1] == "46.0" and r["4"][1] == "46.0"
    assert "* rope 2, 3: held back at rest (piston travel)" in text
    assert "held_back" not in text
    v.show_frame(frame(2), 10.0)
    text = draw(v)
    assert "*" not in text and "held back" not in text
