"""The host data path behind the monitor: two receivers, duplicates, corruption, alarms, ack."""
import io

from rich.console import Console

from ropemon.station.nodefigures import NodeFigures, alarm_settings
from e2e_rig import Rig
from ropemon.station.protocol import Rope, encode_frame

KEY = bytes(range(16))
SITE = NodeFigures([0.0314] * 4, 80_000, 320_000, 0.10, 3.4)


class Clock:
    t = 0.0

    def __call__(self):
        return self.t


def wire(seq, dan=(4600, 4600, 4600, 4600), key=KEY):
    return encode_frame(node=1, seq=seq, time_ms=seq * 100, key=key, battery_mv=3900,
                        ropes=[Rope(d, d, d, 1300) for d in dan])[1]


def session(keys={1: KEY}):
    clk = Clock()
    return Rig(keys, alarm_settings(SITE), SITE, clk), clk


def write_node_json(path, **physical):
    """A node.json whose physical section is the shipped example's with these keys (rated tension
    80 kN, cylinders of 0.0314 m^2, battery low at 3.4 V, and a seal of nearly no friction, so
    that no band widens the alarms these tests are about)."""
    import json

    from ropemon.commission.nodejson import example_physical, seal

    ph = example_physical()
    line = {"intercept": 10.0, "slope": 0.0}
    ph.update(cylinder_area_m2=[0.0314] * 4, rated_rope_tension_N=80_000, imbalance_frac=0.10, battery_low_V=3.4,
              friction=dict(ph["friction"], Fs=line, Fc=line))
    ph.update(physical)
    path.write_text(json.dumps(seal({"physical": ph})))


def screen(s):
    c = Console(width=80, height=24, record=True, file=io.StringIO(), color_system=None)
    c.print(s.view.render(s.clock()))
    return c.export_text()


def test_duplicates_from_both_receivers_reach_the_view_once_and_corruption_is_dropped():
    s, clk = session()
    for seq in range(20):
        clk.t = seq * 0.1
        w = wire(seq)
        if seq != 7:
            s.feed("pithead", w)
        if seq >= 5:
            bad = bytearray(w)
            bad[10] ^= 0x40
            s.feed("mid-shaft", bytes(bad) if seq == 12 else w)
    assert [f.seq for f in s.frames] == list(range(20))           # 7 only via mid-shaft
    assert s.decoders["mid-shaft"].counts.crc_fail == 1
    s.tick()
    text = screen(s)
    assert "pithead: 95 %" in text and "mid-shaft: 70 % crc 1" in text
    assert "frames 20  lost 0 (0.0 %)  duplicates dropped 13" in text  # 14 copies, one was new
    assert s.view.frames == 20


def test_deviation_alarm_raises_rings_and_is_acknowledged():
    s, clk = session()
    for seq in range(30):
        clk.t = seq * 0.1
        s.feed("pithead", wire(seq, dan=(4600, 4600, 5600, 4600)))  # rope 3 +16 %
    s.tick()
    assert s.new_raises == 1
    text = screen(s)
    assert "! NEW DEVIATION rope 3" in text
    s.ack_all()
    assert "ack DEVIATION rope 3" in screen(s)
    assert [e.action for e in s.alarms.events] == ["raise", "ack"]
    assert "acknowledged by tester (test)" in s.alarms.events[-1].message


def test_wrong_key_frames_are_refused_and_raise_link_integrity():
    s, clk = session()
    s.feed("pithead", wire(1, key=b"x" * 16))
    s.tick()                                        # the alarm engine sees link counts each tick
    assert s.frames == [] and s.decoders["pithead"].counts.mac_fail == 1
    assert any(a.kind == "link_integrity" for a in s.alarms.active())


def test_node_silent_alarm_when_frames_stop():
    s, clk = session()
    s.feed("pithead", wire(1))
    clk.t = 10.0
    s.tick()
    assert "NODE" in screen(s) or "SILENT" in screen(s)


def test_a_receiver_whose_port_is_missing_is_shown_down():
    s, clk = session()
    rx = s.add_port("/dev/does-not-exist-ropemon", "pithead", backoff_s=0.01)
    rx.start()
    try:
        import time
        time.sleep(0.1)
        s.tick()
        assert "pithead: -- % crc 0 bad 0  PORT DOWN" in screen(s)
    finally:
        s.close()


def test_live_loop_rings_the_bell_on_a_new_alarm_and_draws_the_screen():
    from ropemon.station.monitor import live_loop
    s, clk = session()
    for seq in range(30):
        clk.t = seq * 0.1
        s.feed("pithead", wire(seq, dan=(4600, 4600, 5600, 4600)))
    out = io.StringIO()
    con = Console(width=80, height=24, file=out, force_terminal=True, color_system=None)
    calls = []
    live_loop(s, s.view, con, refresh_hz=50.0, done=lambda: calls.append(1) or len(calls) > 3)
    text = out.getvalue()
    assert text.count("\a") == 1                   # once for the raise, not per refresh
    assert "DEVIATION rope 3" in text


def test_without_keys_the_screen_says_frames_are_not_authenticated():
    s, clk = session(keys=None)
    s.feed("pithead", wire(1))
    s.tick()
    assert "NO KEY: not authenticated" in screen(s) and len(s.frames) == 1


def test_slack_rope_raises_through_the_settings_built_from_a_node_json(tmp_path):
    """`ropemon config` writes physical.conveyance_weight_N; the monitor's alarm settings turn it into
    the slack floor: 60 % of each rope's share of the empty conveyance load."""
    path = tmp_path / "node.json"
    write_node_json(path, conveyance_weight_N=185_400, slack_frac=0.60)
    site = NodeFigures.from_node_json(path)
    settings = alarm_settings(site)
    floor = round(0.6 * 18_540 / 4)                       # daN
    assert settings.slack_dan == floor and settings.rated_load_dan == 32_000
    clk = Clock()
    s = Rig({1: KEY}, settings, site, clk)
    for seq in range(10):                                 # every rope above the floor: quiet
        clk.t = seq * 0.1
        s.feed("pithead", wire(seq, dan=(4600, 4600, 4600, floor + 100)))
    assert not [a for a in s.alarms.active() if a.kind == "slack"]
    for seq in range(10, 30):                             # rope 4 just below the floor
        clk.t = seq * 0.1
        s.feed("pithead", wire(seq, dan=(4600, 4600, 4600, floor - 20)))
    slack = [a for a in s.alarms.active() if a.kind == "slack"]
    assert [(a.rope, a.present) for a in slack] == [(3, True)]
    s.tick()
    assert "SLACK rope 4" in screen(s)


def test_node_json_without_empty_load_leaves_slack_off_and_a_bad_one_is_refused(tmp_path):
    import pytest

    path = tmp_path / "node.json"
    write_node_json(path)
    assert alarm_settings(NodeFigures.from_node_json(path)).slack_dan is None
    write_node_json(path, conveyance_weight_N=-1)
    with pytest.raises(ValueError, match="physical.conveyance_weight_N"):
        NodeFigures.from_node_json(path)


def test_overload_threshold_is_the_sites_rated_load_times_its_overload_factor(tmp_path):
    """`ropemon config` writes physical.rated_load_N and overload_frac; the overload alarm then
    raises above their product, not above ropes x rated rope tension."""
    import pytest

    path = tmp_path / "node.json"
    phys = {"conveyance_weight_N": 185_400, "rated_load_N": 263_880, "overload_frac": 1.10}
    write_node_json(path, **phys)
    settings = alarm_settings(NodeFigures.from_node_json(path))
    assert settings.rated_load_dan == 26_388 and settings.overload_frac == 1.10
    clk = Clock()
    s = Rig({1: KEY}, settings, NodeFigures.from_node_json(path), clk)
    for seq in range(10):                                 # 28,400 daN: above rated, below 110 %
        clk.t = seq * 0.1
        s.feed("pithead", wire(seq, dan=(7100, 7100, 7100, 7100)))
    assert not [a for a in s.alarms.active() if a.kind == "overload"]
    for seq in range(10, 30):                             # 29,200 daN > 1.10 x 26,388
        clk.t = seq * 0.1
        s.feed("pithead", wire(seq, dan=(7300, 7300, 7300, 7300)))
    assert [a.kind for a in s.alarms.active()] == ["overload"]
    write_node_json(path, **dict(phys, overload_frac=0.9))
    with pytest.raises(ValueError, match="physical.overload_frac"):
        NodeFigures.from_node_json(path)
