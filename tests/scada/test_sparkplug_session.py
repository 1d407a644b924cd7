"""The Sparkplug B session (station/mqtt/session.py) without a broker: driven by hand with a
clock of the test's and an in-memory outbox, what it returns to publish is read back with
ropemon's protobuf. Births then data in seq order (255 -> 0), bdSeq per connection in the
will and NBIRTH, a host's rebirth, a hoist's death and birth, the stored data of a hoist dead
at the births, the DDATA in flight at a disconnect sent again, the primary host's STATE."""
from __future__ import annotations

import json

import pytest

pytest.importorskip("paho.mqtt")   # the package's face imports paho (the session does not)

from ropemon.station.mqtt import sparkplug as sp  # noqa: E402
from ropemon.station.mqtt.outbox import Outbox  # noqa: E402
from ropemon.station.mqtt.session import DEVICE, Message, Session  # noqa: E402

T = 1_700_000_000_000        # the test's clock (ms): every payload is stamped with what it is given
SEQ = "node1/frame_seq"


class Edge:
    """The face's part in miniature: records into the session and an in-memory outbox, the rows
    after the session's cursor out through `row` and `published`, message ids counted as paho's."""

    def __init__(self, bdseq: int = -1, qos: int = 1) -> None:
        devices = {h: sp.hoist_metrics([1]) for h in ("h0", "h1")}
        self.s = Session("mine", "shaft-2", devices, qos=qos, bdseq=bdseq)
        self.outbox = Outbox(None, 100_000)
        self.mid = 0
        self.wire: list[tuple[int, Message]] = []     # (message id, message) as published
        self.now = T

    def put(self, device: str, values: dict, ts: int | None = None) -> None:
        ts = self.now if ts is None else ts
        self.s.taken(device, ts, values)
        self.outbox.add([(device, ts, values)])

    def data(self, device: str, k: int) -> None:
        self.put(device, {SEQ: k, "node1/rope1/tension": 50.0 + k})

    def publish(self, messages: list[Message]) -> list[int]:
        mids = []
        for m in messages:
            self.mid += 1
            self.wire.append((self.mid, m))
            mids.append(self.mid)
        return mids

    def connect(self) -> Message:
        will = self.s.connecting(self.now)
        self.s.connected()
        return will

    def begin(self) -> None:
        self.publish(self.s.begin(self.now, self.outbox))

    def pump(self) -> None:
        """Every row after the cursor, then the DDEATHs due once caught up (the face's loop)."""
        while rows := self.outbox.after(self.s.cursor, 50):
            for row_id, device, ts, values in rows:
                msgs = self.s.row(row_id, device, ts, values, self.now)
                mids = self.publish(msgs)
                mid = next((i for i, m in zip(mids, msgs) if m.row is not None), None)
                self.s.published(row_id, mid)
                if mid is None:
                    self.outbox.delete([row_id])       # nothing in flight: done
        self.publish(self.s.caught_up(self.outbox.next_id, self.now))

    def ack(self, mids) -> None:
        for mid in mids:
            row = self.s.puback(mid)
            if row is not None:
                self.outbox.delete([row])

    def sent(self, since: int = 0) -> list[Message]:
        return [m for _, m in self.wire[since:]]


def kind(m: Message) -> str:
    return m.topic.split("/")[2]


def device(m: Message) -> str | None:
    parts = m.topic.split("/")
    return parts[4] if len(parts) > 4 else None


def seq(m: Message) -> int | None:
    p = sp.decode(m.payload)
    return p.seq if p.HasField("seq") else None


def by_name(m: Message) -> dict:
    return {x.name: sp.metric_value(x) for x in sp.decode(m.payload).metrics}


def ddata(e: Edge, m: Message, dev: str = "h0") -> dict:
    """A DDATA's values by name (DDATA carries aliases only) and whether all are historical."""
    names = {a: n for n, a in e.s.alias[dev].items()}
    ms = sp.decode(m.payload).metrics
    return {"values": {names[x.alias]: sp.metric_value(x) for x in ms}, "historical": all(x.is_historical for x in ms)}


def test_births_then_data_in_seq_order_wrapping_at_255():
    e = Edge()
    e.connect()
    e.begin()
    births = e.sent()
    assert [(kind(m), device(m), m.qos) for m in births] == [("NBIRTH", None, 0), ("DBIRTH", "h0", 0),
                                                              ("DBIRTH", "h1", 0)]
    nb = sp.decode(births[0].payload)
    assert nb.timestamp == T and by_name(births[0]) == {"bdSeq": 0, "Node Control/Rebirth": False}
    dbirth = sp.decode(births[1].payload)
    assert {x.name for x in dbirth.metrics} == {n for n, _, _ in sp.hoist_metrics([1])}
    assert {x.alias for x in dbirth.metrics} == set(e.s.alias["h0"].values())
    for k in range(1, 301):
        e.data("h0", k)
    e.pump()
    data = e.sent(3)
    assert [kind(m) for m in data] == ["DDATA"] * 300 and all(m.qos == 1 and m.row for m in data)
    seqs = [seq(m) for m in e.sent()]
    assert seqs == [i % 256 for i in range(303)]              # NBIRTH 0, one more per message, 255 -> 0
    assert seqs[255:258] == [255, 0, 1]
    got = [ddata(e, m) for m in data]
    assert [g["values"][SEQ] for g in got] == list(range(1, 301))
    assert not any(g["historical"] for g in got)               # queued after the births: live
    assert len(e.s.inflight) == 300 and sorted(e.s.inflight.values()) == [m.row for m in data]


def test_bdseq_is_one_more_per_connection_in_the_will_and_the_nbirth_and_seq_restarts():
    e = Edge(bdseq=254)                    # as the outbox's meta kept it from the last run
    will = e.connect()
    assert (kind(will), will.qos, seq(will), by_name(will)) == ("NDEATH", 1, None, {"bdSeq": 255})
    e.begin()
    e.data("h0", 1)
    e.pump()
    assert by_name(e.sent()[0])["bdSeq"] == 255 and seq(e.sent()[-1]) == 3
    clean = e.s.ndeath(T + 5)
    assert by_name(clean) == {"bdSeq": 255} and seq(clean) is None and sp.decode(clean.payload).timestamp == T + 5
    e.s.disconnected()
    assert not e.s.births
    n = len(e.wire)
    will = e.connect()
    assert by_name(will) == {"bdSeq": 0}                       # 255 -> 0
    e.begin()
    again = e.sent(n)
    assert kind(again[0]) == "NBIRTH" and by_name(again[0])["bdSeq"] == 0
    assert [seq(m) for m in again] == [0, 1, 2]
    assert e.s.sessions == 2 and e.s.bdseq == 0


def rebirth_ncmd(value: bool) -> bytes:
    p = sp.payload(None, T)
    sp.add_metric(p, "Node Control/Rebirth", sp.BOOLEAN, value, T)
    return p.SerializeToString()


def test_a_rebirth_command_gives_nbirth_and_dbirths_with_seq_from_0_in_the_same_session():
    e = Edge()
    e.connect()
    e.begin()
    for k in range(1, 6):
        e.data("h0", k)
    e.pump()
    assert seq(e.sent()[-1]) == 7
    assert e.s.command(rebirth_ncmd(True))
    assert not e.s.command(rebirth_ncmd(False)) and not e.s.command(b"\xff not sparkplug")
    inflight = dict(e.s.inflight)
    n = len(e.wire)
    e.publish(e.s.rebirth(T + 1, e.outbox))
    reborn = e.sent(n)
    assert [(kind(m), device(m), seq(m)) for m in reborn] == [("NBIRTH", None, 0), ("DBIRTH", "h0", 1),
                                                              ("DBIRTH", "h1", 2)]
    assert by_name(reborn[0])["bdSeq"] == 0 and e.s.sessions == 1          # the same session, the same bdSeq
    newest = by_name(reborn[1])
    assert newest[SEQ] == 5 and newest["node1/rope1/tension"] == 55.0      # DBIRTH carries the newest values
    assert e.s.inflight == inflight                                         # the DDATA in flight stay so
    e.data("h0", 6)
    e.pump()
    last = e.sent()[-1]
    assert seq(last) == 3 and not ddata(e, last)["historical"]              # still live after a rebirth


def test_a_hoist_dead_then_heard_again_gives_ddeath_then_dbirth_with_its_newest_values():
    e = Edge()
    e.connect()
    e.begin()
    e.data("h1", 1)
    e.put("h1", {DEVICE: "death"})
    e.put("h1", {"alarms/present": 4})                # a dead hoist's alarm row: not sent ...
    e.data("h0", 1)
    e.put("h1", {DEVICE: "birth"})
    e.data("h1", 2)
    e.pump()
    out = e.sent(3)
    assert [(kind(m), device(m)) for m in out] == [("DDATA", "h1"), ("DDEATH", "h1"), ("DDATA", "h0"),
                                                   ("DBIRTH", "h1"), ("DDATA", "h1")]
    assert [seq(m) for m in out] == [3, 4, 5, 6, 7]
    assert [m.qos for m in out] == [1, 0, 1, 0, 1]
    assert not sp.decode(out[1].payload).metrics                          # DDEATH: no metrics
    assert by_name(out[3])["alarms/present"] == 4                         # ... it goes out with the DBIRTH
    assert ddata(e, out[4], "h1")["values"][SEQ] == 2
    assert e.outbox.rows == 3                                              # only the DDATA await their PUBACK


def test_a_hoist_dead_at_the_births_is_born_for_its_stored_data_then_declared_dead():
    """A previous run's rows (no session yet): h1's data then its death. The births declare h1
    for its stored data, which goes out historical, then its DDEATH; h0 is born as heard."""
    e = Edge()
    e.data("h0", 1)
    e.data("h1", 1)
    e.put("h1", {DEVICE: "death"})
    e.connect()
    e.begin()
    assert [device(m) for m in e.sent() if kind(m) == "DBIRTH"] == ["h0", "h1"]
    e.pump()
    out = e.sent(3)
    assert [(kind(m), device(m)) for m in out] == [("DDATA", "h0"), ("DDATA", "h1"), ("DDEATH", "h1")]
    assert ddata(e, out[0])["historical"] and ddata(e, out[1], "h1")["historical"]
    e.data("h1", 2)                                    # dead: dropped, no seq taken
    e.data("h0", 2)
    e.pump()
    assert [(kind(m), device(m), seq(m)) for m in e.sent(6)] == [("DDATA", "h0", 6)]


def test_a_previous_runs_deaths_and_births_are_not_replayed():
    """Stored rows from before the births: h1 lost and heard again in them; the births find it
    heard, its stored data goes out historical with no DDEATH or DBIRTH among it."""
    e = Edge()
    e.data("h1", 1)
    e.put("h1", {DEVICE: "death"})
    e.put("h1", {DEVICE: "birth"})
    e.data("h1", 2)
    e.connect()
    e.begin()
    e.pump()
    out = e.sent(3)
    assert [(kind(m), device(m), seq(m)) for m in out] == [("DDATA", "h1", 3), ("DDATA", "h1", 4)]
    assert all(ddata(e, m, "h1")["historical"] for m in out)
    assert e.outbox.rows == 2                          # the death and birth rows done at once


def test_the_ddata_in_flight_at_a_disconnect_stay_and_go_out_again_historical():
    """What the face does when the connection is lost: acknowledged rows leave the outbox, the
    DDATA still in flight are dropped from the session but their rows stay, and the next
    session's births start from the outbox's oldest row (historical), live rows after them."""
    e = Edge()
    e.connect()
    e.begin()
    for k in range(1, 6):
        e.data("h0", k)
    e.pump()
    mids = sorted(e.s.inflight)
    e.ack(mids[:2])                                    # frames 1 and 2 acknowledged
    assert e.outbox.rows == 3
    left = e.s.disconnected()
    assert sorted(left) == [3, 4, 5] and not e.s.inflight and not e.s.births
    assert e.s.puback(mids[3]) is None                 # a PUBACK of the old connection: no row
    e.connect()
    e.data("h0", 6)                                    # queued before the births: historical too
    n = len(e.wire)
    e.begin()
    e.data("h0", 7)
    e.pump()
    again = [ddata(e, m) for m in e.sent(n) if kind(m) == "DDATA"]
    assert [(g["values"][SEQ], g["historical"]) for g in again] == [(3, True), (4, True), (5, True), (6, True),
                                                                    (7, False)]
    assert [seq(m) for m in e.sent(n)] == list(range(len(e.sent(n))))
    assert sorted(e.s.inflight.values()) == [3, 4, 5, 6, 7]


def test_qos_0_ddata_and_a_row_of_a_hoist_no_longer_in_the_station_file():
    e = Edge(qos=0)
    e.connect()
    e.begin()
    e.outbox.add([("gone", T, {SEQ: 1})])             # a previous run's row, of a hoist since removed
    e.data("h0", 1)
    e.pump()
    out = e.sent(3)
    assert [(kind(m), device(m), m.qos, seq(m)) for m in out] == [("DDATA", "h0", 0, 3)]
    assert e.outbox.rows == 1                          # the unknown hoist's row done at once


def test_births_wait_for_the_primary_host_online_and_a_stale_state_is_ignored():
    s = Session("mine", "shaft-2", {"h0": sp.hoist_metrics([1])}, primary_host_id="scada")
    s.connecting(T)
    s.connected()
    assert not s.may_be_born()

    def state(online, ts) -> bool:
        return s.host_state(json.dumps({"online": online, "timestamp": ts}).encode())

    assert state(True, 100) is False and s.may_be_born()
    assert state(False, 99) is False and s.may_be_born()       # older than the newest: ignored
    with pytest.raises(ValueError):
        s.host_state(b"not json")
    with pytest.raises(ValueError):
        s.host_state(b'{"online": 1, "timestamp": 5}')
    assert state(False, 101) is True and not s.may_be_born()   # offline: the face ends the session
    s.connected()
    assert not s.may_be_born()                                 # a new connection waits for a new STATE
    assert state(True, 100) is False and not s.may_be_born()   # ... not an older one
    assert Session("mine", "shaft-2", {}).may_be_born()        # no primary host: born at once
