"""Radio model -> two pty pairs -> pyserial readers -> host session: every frame the node
sent arrives at most once, nothing corrupted is accepted, losses are counted."""
import numpy as np

from ropemon.lab import radio
from ropemon.lab.demo import DemoClock, Sent, demo_host, play_to_host, summarize
from ropemon.station.monitor import MonitorView
from ropemon.station.protocol import Rope, decode_raw, encode_frame
from ropemon.station.nodefigures import NodeFigures, alarm_settings

KEY = bytes(range(32))
SITE = NodeFigures([0.0314] * 4, 80_000, 320_000, 0.10, 3.4)


def node_frames(n=400, shaft_m=810.0):
    wires, frames, depth = [], [], []
    for seq in range(n):
        d = shaft_m * seq / (n - 1)
        raw, wire = encode_frame(node=7, seq=seq, time_ms=seq * 100, key=KEY, depth_mm=int(d * 1000),
                                 speed_mm_s=8000, battery_mv=3900,
                                 ropes=[Rope(4600 + i, 4500, 4700, 1300 + seq % 50) for i in range(4)])
        wires.append(wire)
        frames.append(decode_raw(raw, {7: KEY}))
        depth.append(d)
    return Sent(wires, frames), np.array(depth)


def test_frames_cross_the_ptys_once_uncorrupted_and_losses_are_counted():
    sent, depth = node_frames()
    t = np.array([f.time_ms / 1000 for f in sent.frames])
    params = radio.RadioParams(shaft_m=810.0, ber_edge=1e-3)   # plenty of corruption
    result = radio.transmit(zip(t, depth, sent.wires), radio.paper_receivers(810.0), params, seed=5)
    assert sum(d.bit_errors for v in result.deliveries.values() for d in v) > 20
    clock = DemoClock(speed=40.0)
    session = demo_host({7: KEY}, alarm_settings(SITE), clock, None, MonitorView(SITE))
    written = play_to_host(result.deliveries, session, 40.0, clock)
    s = summarize(sent, result, session, {"frames": 0}, written)
    h = s["host"]
    assert h["foreign_frames"] == 0
    seqs = [f.seq for f in session.kept.frames]
    assert len(seqs) == len(set(seqs))                               # each frame at most once
    assert h["frames_received"] + h["frames_lost"] == len(sent.frames)
    assert h["frames_received"] >= len(sent.frames) - result.lost - 10  # the host got what the radio delivered
    assert h["frames_received"] <= len(sent.frames) - result.lost + 10
    assert h["duplicates_dropped"] > 0                               # overlap of the two receivers
    rx = s["receivers"]
    assert rx["pithead"]["crc_fail"] + rx["mid-shaft"]["crc_fail"] > 0
    assert written["pithead"] == sum(len(d.data) for d in result.deliveries["pithead"])
    # link quality by depth: the pithead hears the top, the mid-shaft the bottom
    pit = {a: sh for a, _, sh in rx["pithead"]["share_by_depth"]}
    mid = {a: sh for a, _, sh in rx["mid-shaft"]["share_by_depth"]}
    assert pit[0.0] > 0.9 and (pit.get(800.0) or 0.0) == 0.0
    assert mid[700.0] > 0.3 and (mid.get(0.0) or 0.0) == 0.0
