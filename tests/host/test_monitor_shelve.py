"""The operator shelves and unshelves an alarm from the terminal monitor: `s`, then one digit
each for which alarm, how long and why; `u` then which; any other key cancels. The engine
logs who, and a shelved alarm is shown apart, with its expiry and reason."""
from __future__ import annotations

import io

from rich.console import Console

from host_rig import KEYS
from ropemon.station.monitor import SHELVE_REASONS, MonitorView, handle_keys
from ropemon.station.pipeline import HoistPipeline, station_listeners
from ropemon.station.protocol import encode_frame
from ropemon.station.store import Store


def frames(k0: int, n: int, high: int) -> bytes:
    """n frames of node 1 with rope 4 at `high` daN against 5000 on the others."""
    return b"".join(encode_frame(node=1, seq=k, ropes=[(5000, 5000, 5000, 0)] * 3 + [(high, high, high, 0)],
                                 key=KEYS[1])[1] for k in range(k0, k0 + n))


def screen(view: MonitorView) -> str:
    c = Console(width=80, record=True, file=io.StringIO())
    c.print(view.render(1.8e9 + 3.0))  # the station's clock after `station`
    return c.export_text()


def station(tmp_path, high: int = 6000):
    """A station on a wall clock (as `ropemon monitor`'s) with a store and the view, fed 3 s of
    frames, one each 0.1 s: rope 4 14 % above the mean raises its deviation alarm."""
    store = Store(tmp_path / "hoist.db")
    view = MonitorView()
    clock = [1.8e9]
    s = HoistPipeline(KEYS, station_listeners(None, store, view), clock=lambda: clock[0], resume_from=store)
    for k in range(30):
        s.feed("pithead", frames(k, 1, high))
        s.tick()
        clock[0] += 0.1
    return store, view, s


def test_s_then_three_digits_shelves_the_alarm_with_who_how_long_and_why(tmp_path):
    store, view, s = station(tmp_path)
    with store:
        assert [a.id for a in view.alarms] == ["deviation:n1:r3"]
        assert "s: shelve" in screen(view) and "u: unshelve" not in screen(view)
        handle_keys(s, view, "s", "alice")
        assert "shelve which alarm? 1-1" in screen(view) and "1) ! NEW DEVIATION rope 4" in screen(view)
        handle_keys(s, view, "1", "alice")
        assert "for how long? 1) 15 min  2) 1 h  3) 8 h" in screen(view)
        handle_keys(s, view, "2", "alice")
        assert "why? 1) nuisance" in screen(view)
        handle_keys(s, view, "2", "alice")
        assert view.question is None
        s.pump()
        s.tick()
        ev = [e for e in store.events() if e["action"] == "shelve"]
        assert len(ev) == 1 and ev[0]["alarm"] == "deviation:n1:r3"
        assert ev[0]["operator"] == "alice (terminal)" and SHELVE_REASONS[1] in ev[0]["message"]
        assert view.alarms == [] and [a.id for a in view.shelved] == ["deviation:n1:r3"]
        text = screen(view)
        assert "shelved: deviation rope 4 until" in text and "alarms: none" in text and "u: unshelve" in text
        until = view.shelved[0].shelved_until
        assert 59 * 60 < until - ev[0]["time_s"] <= 60 * 60
        handle_keys(s, view, "u", "bob")
        assert "unshelve: 1) deviation:n1:r3" in screen(view)
        handle_keys(s, view, "1", "bob")
        s.pump()
        s.tick()
        assert [e["operator"] for e in store.events() if e["action"] == "unshelve"] == ["bob (terminal)"]
        assert view.shelved == [] and [a.id for a in view.alarms] == ["deviation:n1:r3"]


def test_any_key_not_offered_cancels_and_nothing_is_shelved(tmp_path):
    store, view, s = station(tmp_path)
    with store:
        for keys in (["s", "x"], ["s", "2"], ["s", "1", "4"], ["s", "1", "1", "0"], ["s", "q"]):
            for k in keys:
                assert handle_keys(s, view, k, "alice")   # `q` inside a question cancels it, not quits
            assert view.question is None, keys
        s.pump()
        assert not [e for e in store.events() if e["action"] == "shelve"]
        assert "a: acknowledge alarms   s: shelve" in screen(view)


def test_s_and_u_ask_nothing_without_an_alarm_to_shelve_or_unshelve(tmp_path):
    store, view, s = station(tmp_path, high=5000)
    with store:
        assert view.frames == 30 and view.alarms == []
        handle_keys(s, view, "s", "alice")
        handle_keys(s, view, "u", "alice")
        assert view.question is None and "shelve" not in screen(view)
