"""The station's spine: listeners in order, messages published back, a failing listener, and
operator commands from another thread reaching the decoders only through their own thread."""
from __future__ import annotations

import threading

from host_rig import KEYS
from ropemon.station.alarms import AlarmEvent, AlarmSettings
from ropemon.station.decoder import SEQ_COUNT_BITS
from ropemon.station.pipeline import (AcceptRewound, Acknowledge, AlarmListener, AlarmState, Listener, HoistPipeline,
                                      StationStatus)
from ropemon.station.protocol import encode_frame


def w(seq: int, tension: int = 500, node: int = 1, boot: int = 0) -> bytes:
    return encode_frame(node=node, seq=(boot << SEQ_COUNT_BITS) | seq, time_ms=seq * 100,
                        ropes=[(tension, tension, tension, 0)] * 4, key=KEYS[node])[1]


class Recorder(Listener):
    def __init__(self, name: str, log: list) -> None:
        self.name, self.log = name, log

    def on_frame(self, item, now_s):
        self.log.append((self.name, "frame", item.frame.seq))

    def on_event(self, event):
        self.log.append((self.name, "event", event.alarm))

    def on_status(self, status):
        self.log.append((self.name, "status", sorted(status.receivers)))

    def on_alarms(self, state):
        self.log.append((self.name, "alarms", len(state.active)))

    def on_command(self, command, now_s):
        self.log.append((self.name, "command", type(command).__name__))

    def on_stop(self, status):
        self.log.append((self.name, "stop", None))


class Echo(Listener):
    """Publishes an event for every frame: it must reach every listener, after the frame."""

    name = "echo"

    def on_frame(self, item, now_s):
        self.publish(AlarmEvent(time_s=now_s, action="raise", alarm=f"echo:{item.frame.seq}", kind="echo", node=1,
                                message="echo"))


def test_messages_reach_every_listener_in_order_and_published_ones_follow():
    log: list = []
    s = HoistPipeline(KEYS, [Recorder("a", log), Echo(), Recorder("b", log)], clock=lambda: 1.0)
    s.feed("pithead", w(0) + w(1))
    s.feed("mid-shaft", w(1))                     # a duplicate: no listener sees it
    assert log == [("a", "frame", 0), ("b", "frame", 0), ("a", "event", "echo:0"), ("b", "event", "echo:0"),
                   ("a", "frame", 1), ("b", "frame", 1), ("a", "event", "echo:1"), ("b", "event", "echo:1")]
    log.clear()
    st = s.tick()
    assert isinstance(st, StationStatus) and st.authenticated and st.time_s == 1.0
    assert log == [("a", "status", ["mid-shaft", "pithead"]), ("b", "status", ["mid-shaft", "pithead"])]
    assert st.receivers["pithead"].counts.frames_ok == 2 and st.receivers["mid-shaft"].url is None
    log.clear()
    s.close()
    assert log == [("a", "stop", None), ("b", "stop", None)]


def test_the_alarm_listener_publishes_events_and_state_and_takes_the_operators_ack():
    log: list = []
    clk = [0.0]
    alarms = AlarmListener(AlarmSettings())
    s = HoistPipeline(KEYS, [alarms, Recorder("view", log)], clock=lambda: clk[0])
    for k in range(12):                           # rope 4 at +~27 % of the mean
        clk[0] = k * 0.1
        s.feed("pithead", encode_frame(node=1, seq=k, time_ms=k * 100, key=KEYS[1],
                                       ropes=[(500, 500, 500, 0)] * 3 + [(700, 700, 700, 0)])[1])
    raised = [e for e in log if e[1] == "event"]
    assert raised == [("view", "event", "deviation:n1:r3")]
    assert ("view", "alarms", 1) in log           # the state follows the event
    log.clear()
    s.submit(Acknowledge("carol", "web"))
    s.pump()
    assert log == [("view", "command", "Acknowledge"), ("view", "event", "deviation:n1:r3"), ("view", "alarms", 1)]
    ack = alarms.engine.events[-1]
    assert ack.action == "ack" and ack.message.startswith("acknowledged by carol (web): rope 4")


class Broken(Listener):
    name = "broken store"

    def on_frame(self, item, now_s):
        raise OSError("database or disk is full")


def test_a_failing_listener_does_not_stop_the_others_and_is_reported():
    log: list = []
    s = HoistPipeline(None, [Broken(), Recorder("view", log)], clock=lambda: 2.0)
    s.feed("pithead", w(0) + w(1))
    assert [e for e in log if e[1] == "frame"] == [("view", "frame", 0), ("view", "frame", 1)]
    errors = [e for e in log if e[1] == "event"]
    assert errors == [("view", "event", "listener_error:broken store")]    # once until the next tick
    st = s.tick()
    assert st.listener_errors == {"broken store": (2, "OSError: database or disk is full")}
    s.feed("pithead", w(2))
    assert len([e for e in log if e[1] == "event"]) == 2                    # once more after a tick


def test_accepting_a_rewound_node_from_another_thread_reaches_each_decoder_through_its_own_thread():
    log: list = []
    s = HoistPipeline(KEYS, [Recorder("view", log)])
    pit = s.hub.feeder("pithead")
    pit(w(0, boot=7) + w(0, boot=0))              # the node's flash was wiped: refused
    s.pump()
    assert s.hub.rewound() == {1: (7, 0)}
    t = threading.Thread(target=s.submit, args=(AcceptRewound("dave", "terminal", node=1),))
    t.start()
    t.join()
    s.pump()                                      # the command runs on the station's thread ...
    assert ("view", "command", "AcceptRewound") in log
    assert ("view", "event", "rewound:n1") in log
    assert s.decoders["pithead"].replay._rebase == set()   # ... and waits in the receiver's inbox
    done = threading.Event()

    def reader():                                 # the receiver's own thread applies it
        pit(w(1, boot=0))
        done.set()
    threading.Thread(target=reader).start()
    assert done.wait(5)
    s.pump()
    assert ("view", "frame", 1) in log and s.hub.rewound() == {}
    assert [e for e in log if e == ("view", "event", "rewound:n1")] == [("view", "event", "rewound:n1")] * 2


def test_alarm_state_carries_bands_only_with_the_seal_lines():
    states: list[AlarmState] = []

    class Keep(Listener):
        def on_alarms(self, state):
            states.append(state)

    s = HoistPipeline(None, [AlarmListener(), Keep()], clock=lambda: 0.0)
    s.feed("pithead", w(0))
    s.tick()
    assert states[-1].active == () and states[-1].bands == {1: []}


def test_a_full_disk_keeps_the_station_alarming_and_loses_no_frame_once_space_returns(tmp_path):
    """The log's file may not grow (SQLite's max_page_count: what a full disk looks like to it):
    frames still reach the alarms and the views, STATION FAULT is raised with the reason, the
    frames wait in memory; once there is room they are stored, in order, exactly once."""
    from ropemon.station.pipeline import StoreListener
    from ropemon.station.store import Store

    clk = [0.0]
    store = Store(tmp_path / "hoist.db", batch_frames=5)
    pages = store.db.execute("PRAGMA page_count").fetchone()[0]
    store.db.execute(f"PRAGMA max_page_count = {pages + 2}")
    log: list = []
    alarms = AlarmListener(AlarmSettings(silent_s=60.0))
    s = HoistPipeline(KEYS, [alarms, StoreListener(store, clock=lambda: clk[0]), Recorder("view", log)],
                      clock=lambda: clk[0])
    seqs = []
    for k in range(400):
        clk[0] = k * 0.1
        s.feed("pithead", w(k, tension=500 + k % 7))
        seqs.append(k)
        if k % 3 == 0:
            s.tick()
    assert [e for e in log if e[1] == "frame"] == [("view", "frame", k) for k in seqs]   # nothing held up
    active = {a.id: a for a in alarms.engine.active()}
    assert "station_fault:store" in active and active["station_fault:store"].present
    assert "database or disk is full" in active["station_fault:store"].message
    assert "frames and" in active["station_fault:store"].message
    stored_while_full = store.db.execute("SELECT count(*) FROM frames").fetchone()[0]
    assert stored_while_full < 400

    store.db.execute("PRAGMA max_page_count = 1073741823")       # space again
    for k in range(400, 420):
        clk[0] = 40.0 + (k - 400) * 0.5
        s.feed("pithead", w(k))
        seqs.append(k)
        s.tick()
    s.close()
    rows = [r[0] for r in store.db.execute("SELECT seq FROM frames ORDER BY id")]
    assert rows == seqs                                            # every frame, once, in order
    kinds = [r[0] for r in store.db.execute("SELECT action FROM events WHERE kind = 'station_fault'")]
    assert kinds == ["raise", "clear"]                             # and the log says so
    assert not [a for a in alarms.engine.active() if a.kind == "station_fault" and a.present]
    store.close()


def active_ids(alarms: AlarmListener) -> list[str]:
    return sorted(a.id for a in alarms.engine.active() if a.present)


def test_a_dead_receiver_and_a_configured_node_never_heard_raise_alarms_within_the_set_seconds():
    """A wrong port: nothing is ever heard. The station does not stay quiet: RECEIVER DOWN (with the
    device and the reason) after receiver_down_s, and the configured node SILENT after silent_s."""
    clk = [0.0]
    alarms = AlarmListener(AlarmSettings(silent_s=5.0, receiver_down_s=2.0, nodes=(1,)))
    s = HoistPipeline(KEYS, [alarms], clock=lambda: clk[0])
    s.add_port("/dev/ropemon-no-such-port", "pithead", backoff_s=0.01).start()
    try:
        for k in range(9):                     # 0 .. 2 s
            clk[0] = k * 0.25
            s.tick()
        assert active_ids(alarms) == []        # within the configured seconds: not yet
        for k in range(9, 25):                 # .. 6 s
            clk[0] = k * 0.25
            s.tick()
        assert active_ids(alarms) == ["receiver_down:pithead", "silent:n1"]
        down = [a for a in alarms.engine.active() if a.kind == "receiver_down"][0]
        assert "/dev/ropemon-no-such-port" in down.message and "open" in down.message
    finally:
        s.close()


def test_no_frame_from_any_node_is_an_alarm_without_a_configured_node_and_clears_on_a_frame():
    clk = [0.0]
    alarms = AlarmListener(AlarmSettings(silent_s=5.0))
    s = HoistPipeline(None, [alarms], clock=lambda: clk[0])
    for k in range(30):
        clk[0] = k * 0.25
        s.tick()
    assert active_ids(alarms) == ["no_data"]
    for k in range(30, 50):
        clk[0] = k * 0.25
        s.feed("pithead", encode_frame(node=3, seq=k, ropes=[(500, 500, 500, 0)] * 4)[1])
        s.tick()
    assert active_ids(alarms) == []


def test_the_nodes_own_imbalance_bit_is_alarmed_only_where_asked():
    """By default the node's imbalance bit raises nothing (DEVIATION alarms on the same means);
    with `node_imbalance` (the evaluation's legacy station) it raises NODE IMBALANCE."""
    from ropemon.station.protocol import L
    for on, want in ((True, ["node_imbalance:n1"]), (False, [])):
        clk = [0.0]
        alarms = AlarmListener(AlarmSettings(node_imbalance=on))
        s = HoistPipeline(None, [alarms], clock=lambda: clk[0])
        for k in range(5):
            clk[0] = k * 0.1
            s.feed("pithead", encode_frame(node=1, seq=k, status=L.ST_IMBALANCE, ropes=[(500, 500, 500, 0)] * 4)[1])
        assert active_ids(alarms) == want


def test_an_old_frame_replayed_into_the_other_receiver_is_refused_and_counted():
    """Pithead heard seq 0-99, mid-shaft 100-6000 (the cage stood at the bottom); copies of
    1000-1004 sent into pithead are replays, not current data, although pithead never had them."""
    log: list = []
    clk = [0.0]
    alarms = AlarmListener(AlarmSettings())
    s = HoistPipeline(KEYS, [alarms, Recorder("view", log)], clock=lambda: clk[0])
    s.feed("pithead", b"".join(w(k) for k in range(100)))
    s.feed("mid-shaft", b"".join(w(k) for k in range(100, 6001)))
    log.clear()
    s.feed("pithead", b"".join(w(k) for k in range(1000, 1005)))
    assert [e for e in log if e[1] == "frame"] == []
    assert s.decoders["pithead"].counts.replayed == 5
    s.tick()
    assert "link_integrity:pithead" in active_ids(alarms)
    # a late frame a few behind that no receiver delivered yet is a gap filled, not a replay
    s.feed("mid-shaft", w(6003))
    s.feed("pithead", w(6002))
    assert [e for e in log if e[1] == "frame"] == [("view", "frame", 6003), ("view", "frame", 6002)]
    assert s.decoders["pithead"].counts.replayed == 5


def test_shelving_goes_through_the_command_path_and_a_bad_command_is_refused_and_logged():
    from ropemon.station.pipeline import Shelve, Unshelve
    log: list = []
    clk = [0.0]
    alarms = AlarmListener(AlarmSettings())
    s = HoistPipeline(None, [alarms, Recorder("view", log)], clock=lambda: clk[0])
    for k in range(12):
        clk[0] = k * 0.1
        s.feed("pithead", encode_frame(node=1, seq=k, ropes=[(500, 500, 500, 0)] * 3 + [(700, 700, 700, 0)])[1])
    s.submit(Shelve("erin", "web", alarm="deviation:n1:r3", minutes=30, reason=""))
    s.submit(Shelve("erin", "web", alarm="deviation:n1:r3", minutes=30, reason="rope change"))
    s.pump()
    events = [e for e in alarms.engine.events if e.action in ("refused", "shelve")]
    assert [e.action for e in events] == ["shelve"]
    assert alarms.engine.hidden()[0].note == "rope change (erin (web))"
    s.submit(Unshelve("erin", "web", alarm="nope"))
    s.pump()
    assert ("view", "event", "nope") in log                    # refused: published and logged
