"""The operator accepts a node refused for a rewound boot counter in the monitor: the `r` `y`
keys, every receiver's decoder, and the audit event in the log (who, when, which node)."""
from __future__ import annotations

import io

from rich.console import Console

from host_rig import KEYS
from ropemon.station.decoder import SEQ_COUNT_BITS
from ropemon.station.monitor import MonitorView, handle_keys, operator_name
from ropemon.station.pipeline import AcceptRewound, HoistPipeline, station_listeners
from ropemon.station.protocol import encode_frame
from ropemon.station.store import Store


def w(boot: int, k: int) -> bytes:
    return encode_frame(node=1, seq=(boot << SEQ_COUNT_BITS) | k, ropes=[(500, 500, 500, 0)] * 4, key=KEYS[1])[1]


def screen(view: MonitorView) -> str:
    c = Console(width=80, record=True, file=io.StringIO())
    c.print(view.render(0.0))
    return c.export_text()


def test_refused_node_is_shown_and_accepted_with_r_then_y(tmp_path):
    with Store(tmp_path / "hoist.db") as store:
        view = MonitorView()
        s = HoistPipeline(KEYS, station_listeners(None, store, view), resume_from=store)
        s.feed("pithead", w(7, 0) + w(7, 1))
        s.feed("mid-shaft", w(7, 1))
        s.feed("pithead", w(0, 0))            # the node's flash was wiped
        s.feed("mid-shaft", w(0, 0))
        s.tick()
        assert view.refused == {1: (7, 0)}
        assert "NODE 1 REFUSED: boot counter went back 7 -> 0" in screen(view)
        assert "r: accept node 1" in screen(view)
        assert handle_keys(s, view, "r", "alice")
        assert view.confirm_accept == 1 and "y: yes" in screen(view)
        assert handle_keys(s, view, "x", "alice")     # anything but y: no
        assert view.confirm_accept is None
        assert not [e for e in store.events() if e["action"] == "accept"]
        handle_keys(s, view, "r", "alice")
        handle_keys(s, view, "y", "alice")
        assert not [e for e in store.events() if e["action"] == "accept"]   # a command: done at the next pump
        s.pump()
        acc = [e for e in store.events() if e["action"] == "accept"]
        assert len(acc) == 1
        e = acc[0]
        assert (e["alarm"], e["kind"], e["node"], e["value"], e["threshold"]) == ("rewound:n1", "rewound", 1, 7, 0)
        assert "operator alice accepted node 1" in e["message"] and "UTC" in e["message"]
        assert e["time_s"] > 1.6e9             # wall-clock time, not a monotonic clock
        n = view.frames
        s.feed("pithead", w(0, 1))
        s.feed("mid-shaft", w(0, 1) + w(0, 2))  # both receivers take the new baseline
        assert view.frames == n + 2
        s.tick()
        assert view.refused == {} and "REFUSED" not in screen(view)
        assert all(d.counts.rewound == 1 for d in s.decoders.values())


def test_r_does_nothing_without_a_refused_node_and_q_quits():
    view = MonitorView()
    s = HoistPipeline(KEYS, [view])
    s.feed("pithead", w(1, 0))
    s.tick()
    assert handle_keys(s, view, "r", "bob") and view.confirm_accept is None
    assert handle_keys(s, view, "q", "bob") is False


def test_accept_up_front_is_logged_and_reaches_the_decoders(tmp_path):
    with Store(tmp_path / "hoist.db") as store:
        view = MonitorView()
        s = HoistPipeline(KEYS, station_listeners(None, store, view), accept_rewound=[1], resume_from=store)
        s.submit(AcceptRewound(operator_name(), "command line", node=1, how="with --accept-rewound"))
        s.pump()
        ev = store.events()[0]
        assert ev["action"] == "accept" and ev["value"] is None
        assert "with --accept-rewound" in ev["message"]
        s.feed("pithead", w(7, 0) + w(0, 0) + w(0, 1))
        assert view.frames == 3
