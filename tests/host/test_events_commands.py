"""AlarmEvent's named fields and the log's form of them, old rows read back; a command's outcome
given back to its sender by the station (`ropemon.station.events`, `ropemon.station.commands`)."""
from __future__ import annotations

import sqlite3
import threading

import pytest

from host_rig import KEYS
from ropemon.station.alarms import AlarmSettings
from ropemon.station.commands import CommandOutcome
from ropemon.station.decoder import SEQ_COUNT_BITS
from ropemon.station.events import AlarmEvent
from ropemon.station.pipeline import (AcceptRewound, Acknowledge, AlarmListener, Listener, RemoveFromService, Shelve,
                                      HoistPipeline, Unshelve)
from ropemon.station.protocol import encode_frame
from ropemon.station.store import Store

#: the keys every event's to_dict had before the named fields
OLD_KEYS = {"time_s", "action", "alarm", "kind", "node", "rope", "value", "threshold", "message", "worst", "operator",
            "annunciated"}


def test_an_event_is_built_from_named_fields_only():
    e = AlarmEvent(time_s=1.0, action="raise", alarm="deviation:n1:r2", kind="deviation", node=1, rope=2,
                   value=0.12, threshold=0.1, message="rope 3 +12 %")
    assert (e.worst, e.operator, e.annunciated, e.seq, e.count) == (None, None, True, None, None)
    with pytest.raises(TypeError):
        AlarmEvent(1.0, "raise", "deviation:n1:r2", "deviation", 1, 2, 0.12, 0.1, "rope 3 +12 %")  # type: ignore[misc]
    assert e.columns() == (0.12, 0.1) and e.to_dict()["value"] == 0.12


@pytest.mark.parametrize("event, value, threshold", [
    (AlarmEvent(time_s=5.0, action="rebase", alarm="rewound:n1", kind="rewound", node=1, seq=(2 << SEQ_COUNT_BITS) | 3,
                prev_seq=(7 << SEQ_COUNT_BITS) | 40, message="baseline"), (2 << SEQ_COUNT_BITS) | 3,
     (7 << SEQ_COUNT_BITS) | 40),
    (AlarmEvent(time_s=5.0, action="accept", alarm="rewound:n1", kind="rewound", node=1, newest_boot=7, frame_boot=0,
                message="accepted"), 7, 0),
    (AlarmEvent(time_s=5.0, action="error", alarm="link_error:pithead", kind="link_error", count=3,
                message="3 errors"), 3, None),
])
def test_a_station_events_numbers_have_names_and_keep_the_logs_and_the_faces_form(event, value, threshold):
    assert event.value is None and event.threshold is None       # not reused: in their own fields
    assert event.columns() == (value, threshold)
    d = event.to_dict()
    assert OLD_KEYS <= set(d) and (d["value"], d["threshold"]) == (value, threshold)
    row = event.row()
    assert (row["value"], row["threshold"]) == (value, threshold) and "seq" not in row
    assert AlarmEvent.from_row(row) == event


def test_the_headless_json_lines_show_a_station_events_numbers_where_they_always_were():
    import io
    import json
    from ropemon.station.monitor import JsonAlarmLines
    out = io.StringIO()
    JsonAlarmLines(out).on_event(AlarmEvent(time_s=5.0, action="rebase", alarm="rewound:n1", kind="rewound", node=1,
                                            seq=9, prev_seq=4, message="baseline"))
    line = json.loads(out.getvalue())
    assert (line["event"], line["value"], line["threshold"]) == ("rebase", 9, 4)


def _old_rows(path) -> None:
    """Events as the station logged them before the named fields: the numbers in value/threshold."""
    db = sqlite3.connect(path)
    cols = "time_s, action, alarm, kind, node, rope, value, threshold, message, worst, operator"
    db.executemany(f"INSERT INTO events ({cols}) VALUES (?,?,?,?,?,?,?,?,?,?,?)", [
        (1.0, "raise", "deviation:n1:r2", "deviation", 1, 2, 0.12, 0.1, "rope 3 +12 %", 0.12, None),
        (2.0, "accept", "rewound:n1", "rewound", 1, None, 7, 0, "operator dave accepted node 1", None, None),
        (3.0, "rebase", "rewound:n1", "rewound", 1, None, 5, (7 << SEQ_COUNT_BITS) | 40, "baseline", None, None),
        (4.0, "error", "listener_error:web", "listener_error", None, None, 2, None, "web failed", None, None),
        (5.0, "refused", "nope", "command", None, None, None, None, "Unshelve by erin (web) refused: no alarm 'nope'",
         None, "erin (web)"),
    ])
    db.commit()
    db.close()


def test_an_old_logs_event_rows_read_back_the_same_and_new_events_are_stored_alike(tmp_path):
    old, new = tmp_path / "old.db", tmp_path / "new.db"
    Store(old).close()
    _old_rows(old)
    with Store(old, readonly=True) as s:
        rows = s.events()
    events = [AlarmEvent.from_row(r) for r in rows]
    assert [(e.action, e.value, e.seq, e.prev_seq, e.newest_boot, e.frame_boot, e.count) for e in events] == [
        ("raise", 0.12, None, None, None, None, None),
        ("accept", None, None, None, 7, 0, None),
        ("rebase", None, 5, (7 << SEQ_COUNT_BITS) | 40, None, None, None),
        ("error", None, None, None, None, None, 2),
        ("refused", None, None, None, None, None, None)]
    assert events[4].operator == "erin (web)"
    with Store(new) as s:
        for e in events:
            s.add_event(e)
        again = s.events()
    strip = [{k: v for k, v in r.items() if k != "id"} for r in rows]
    assert [{k: v for k, v in r.items() if k != "id"} for r in again] == strip     # the same rows


def _frame(seq: int, boot: int = 0, tensions=(500, 500, 500, 700)) -> bytes:
    return encode_frame(node=1, seq=(boot << SEQ_COUNT_BITS) | seq, time_ms=seq * 100,
                        ropes=[(t, t, t, 0) for t in tensions], key=KEYS[1])[1]


class Events(Listener):
    name = "events"

    def __init__(self) -> None:
        self.got: list[AlarmEvent] = []

    def on_event(self, event: AlarmEvent) -> None:
        self.got.append(event)


def _deviating_station():
    clk = [0.0]
    alarms, seen = AlarmListener(AlarmSettings()), Events()
    s = HoistPipeline(KEYS, [alarms, seen], clock=lambda: clk[0])
    for k in range(12):
        clk[0] = k * 0.1
        s.feed("pithead", _frame(k))
    assert "deviation:n1:r3" in [a.id for a in alarms.engine.active()]
    return s, seen


def test_a_command_from_another_thread_gets_its_outcome_and_a_refusal_is_still_published():
    s, seen = _deviating_station()
    tickets = {}

    def face():
        tickets["bad"] = s.submit(Unshelve("erin", "web", alarm="nope"))
        tickets["reasonless"] = s.submit(RemoveFromService("erin", "web", alarm="deviation:n1:r3", reason=" "))
        tickets["ack"] = s.submit(Acknowledge("olga", "opcua", alarm="deviation:n1:r3"))
    t = threading.Thread(target=face)
    t.start()
    t.join()
    assert not any(tk.done() for tk in tickets.values())       # carried out at the next pump only
    s.pump()
    bad, reasonless, ack = (tickets[k].result(timeout=0) for k in ("bad", "reasonless", "ack"))
    assert bad == CommandOutcome(False, "nope", "unshelve", "no alarm 'nope'")
    assert not reasonless.ok and reasonless.action == "out_of_service" and "reason" in reasonless.reason
    assert ack == CommandOutcome(True, "deviation:n1:r3", "ack") and ack.command.via == "opcua"
    refused = [e for e in seen.got if e.action == "refused"]
    assert [(e.alarm, e.operator) for e in refused] == [("nope", "erin (web)"), ("deviation:n1:r3", "erin (web)")]


def test_a_shelve_carried_out_and_an_accept_rewound_have_their_outcomes():
    s, _ = _deviating_station()
    shelve = s.submit(Shelve("olga", "web", alarm="deviation:n1:r3", minutes=30, reason="rope change"))
    accept = s.submit(AcceptRewound("dave", "terminal", node=1))
    s.pump()
    assert shelve.result(timeout=0) == CommandOutcome(True, "deviation:n1:r3", "shelve")
    assert accept.result(timeout=0) == CommandOutcome(True, "rewound:n1", "accept")


def test_a_command_nothing_carries_out_is_refused_to_its_sender():
    s = HoistPipeline(KEYS, [Events()])                 # no alarm engine
    t = s.submit(Acknowledge("olga", "web"))
    s.pump()
    out = t.result(timeout=0)
    assert not out.ok and out.reason == "nothing in the station carried it out"
