"""Two-receiver merge on crafted streams: duplicates, gaps, late frames, link quality by depth."""
from __future__ import annotations

from ropemon.station.decoder import StreamDecoder
from ropemon.station.merge import RESTART_BACK, Merger
from ropemon.station.protocol import encode_frame


def frame(seq: int, node: int = 1, depth_m: float = 0.0):
    _, wire = encode_frame(node=node, seq=seq, ropes=[(1000, 990, 1010, 5000)] * 4, depth_mm=int(depth_m * 1000))
    return StreamDecoder().feed(wire)[0]


def test_duplicates_and_gaps_across_two_receivers():
    m = Merger()
    a = [0, 1, 2, 5, 6, 8, 9]          # pithead hears the top of the shaft
    b = [2, 3, 6, 9, 10, 12]           # mid-shaft; seq 4, 7 and 11 reach nobody
    new_a = [m.add("pithead", frame(s)) for s in a]
    new_b = [m.add("midshaft", frame(s)) for s in b]
    assert new_a == [True] * 7
    assert new_b == [False, True, False, False, True, True]
    st = m.stats()[1]
    assert st["unique"] == 10          # 0,1,2,3,5,6,8,9,10,12
    assert st["duplicates"] == 3
    assert st["lost"] == 3             # 4, 7, 11 (3 arrived late from midshaft: not lost)
    assert st["receivers"]["pithead"] == {"delivered": 7, "share": 7 / 13}
    assert st["receivers"]["midshaft"] == {"delivered": 6, "share": 6 / 13}
    assert st["last_seq"] == 12


def test_late_frame_fills_its_gap_and_repeats_from_one_receiver_count_once():
    m = Merger()
    assert m.add("a", frame(10)) and m.add("a", frame(14))
    assert m.stats()[1]["lost"] == 3
    assert m.add("b", frame(12))
    assert not m.add("b", frame(12))
    st = m.stats()[1]
    assert st["lost"] == 2 and st["unique"] == 3 and st["duplicates"] == 1
    assert st["receivers"]["b"]["delivered"] == 1


def test_link_quality_by_depth_bin():
    m = Merger(depth_bin_m=100)
    for s in range(20):
        depth = s * 20.0  # 0..380 m
        f = frame(s, depth_m=depth)
        if depth < 200:
            m.add("pithead", f)
        if depth >= 100 and s % 2 == 0:
            m.add("midshaft", f)
    bins = {b["depth_from_m"]: b for b in m.stats()[1]["by_depth"]}
    assert bins[0.0]["share"] == {"pithead": 1.0, "midshaft": 0.0}
    assert bins[100.0]["share"] == {"pithead": 1.0, "midshaft": 0.4}
    # Below 200 m only midshaft, every other frame: the gaps are charged to the depth where they show.
    assert bins[200.0]["sent"] == 5 and bins[200.0]["share"]["midshaft"] == 3 / 5
    # seq 19 was lost with nothing after it to reveal the gap: not counted yet.
    assert bins[300.0]["sent"] == 4 and bins[300.0]["share"] == {"pithead": 0.0, "midshaft": 0.5}


def test_nodes_are_independent_and_a_counter_restart_is_detected():
    m = Merger()
    assert m.add("a", frame(5, node=1)) and m.add("a", frame(5, node=2))
    assert m.add("a", frame(RESTART_BACK + 100, node=1))
    assert m.add("a", frame(0, node=1))  # far behind: the node restarted, not a duplicate
    st = m.stats()
    assert st[1]["restarts"] == 1 and st[2]["restarts"] == 0
    assert st[2]["unique"] == 1


def test_node_reset_to_seq_zero_is_a_restart_not_duplicates():
    m = Merger()
    for s in range(100):
        assert m.add("a", frame(s, depth_m=1.0))
    # The node resets: seq 0, 1, ... again, with other contents (here: depth).
    assert m.add("a", frame(0, depth_m=2.0))
    assert m.add("a", frame(1, depth_m=2.0))
    assert not m.add("b", frame(1, depth_m=2.0))  # the other receiver's copy is a duplicate
    assert m.add("a", frame(3, depth_m=2.0))
    st = m.stats()[1]
    assert st["restarts"] == 1
    assert st["unique"] == 103 and st["duplicates"] == 1 and st["lost"] == 1


def test_loss_count_does_not_depend_on_arrival_order():
    import random
    seqs = [s for s in range(200) if s % 7 and s % 11]  # the frames that got through
    want_lost = 200 - len(seqs) - (199 - max(seqs)) - min(seqs)
    for seed in range(5):
        order = seqs[:]
        random.Random(seed).shuffle(order)
        m = Merger()
        for s in order:
            assert m.add("a", frame(s))
        st = m.stats()[1]
        assert st["lost"] == want_lost and st["unique"] == len(seqs)
        assert sum(b["sent"] for b in st["by_depth"]) == len(seqs) + want_lost
