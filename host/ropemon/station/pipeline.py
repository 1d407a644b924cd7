"""One hoist's data path, `HoistPipeline`: receivers -> decode and merge -> listeners.

    receivers          one reader thread per port (`link.SerialReceiver`)       transport
      -> FrameHub      a decoder per receiver, one merger, a queue (`link`)     protocol
      -> HoistPipeline one consumer thread: `pump` and `tick`                   spine
      -> listeners     alarm engine, store, terminal view, ...                  fan-out

A listener knows none of the others: it receives messages from the station and
may publish messages back, which the station hands to every listener after the
current one (in the order the listeners were added):

    on_frame(Received, now_s)   a merged frame, new (not a duplicate)
    on_event(AlarmEvent)        an alarm raised, cleared or acknowledged; an operator's
                                decision; a rebase; a receiver's or listener's error
    on_status(StationStatus)    each `tick`: receivers, merge figures, refused nodes
    on_alarms(AlarmState)       the active alarms and deviation bands (the alarm listener's)
    on_command(Command, now_s)  an operator action; the listener that carries it out returns
                                its `CommandOutcome` (`ropemon.station.commands`)
    on_stop(StationStatus)      the station closes: log and commit what is pending

Every listener method runs on the station's thread (the one calling `pump`,
`tick` and `close`); a listener that serves another thread (a web server)
copies what it needs. Operator actions come in through `submit`, from any
thread, and run at the next `pump`: acknowledging goes to the listeners (the
alarm listener acts on it); accepting a rewound node goes to the hub, which
leaves it in each receiver's inbox for that receiver's own thread. `submit`
returns a future the station settles with the command's outcome (carried out,
or refused and why): the face that sent it knows its own result by that alone.

A listener that raises does not stop the others: the station counts it, and
publishes one `listener_error` event per listener and tick while it keeps failing.
Each tick's status names the parts failing now (`faults`: a listener that raised
since the last tick, or whose `health()` says what is wrong); the alarm listener
raises STATION FAULT for each.
"""
from __future__ import annotations

import datetime
import queue
import sqlite3
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

from ropemon.station.alarms import ActiveAlarm, AlarmEngine, AlarmEvent, AlarmSettings
from ropemon.station.commands import (AcceptRewound, Acknowledge, Command, CommandOutcome,  # noqa: F401
                                      RemoveFromService, ReturnToService, Shelve, Ticket, Unshelve, settle)
from ropemon.station.decoder import DUPLICATE_MEMORY, SEQ_COUNT_BITS, StreamDecoder
from ropemon.station.link import FrameHub, Received, ReceiverStatus, SerialReceiver
from ropemon.station.uncertainty import DeviationBand


# -- messages ----------------------------------------------------------------------


@dataclass(frozen=True)
class StationStatus:
    """What the station knows of its links at one moment."""

    time_s: float
    receivers: dict[str, ReceiverStatus]
    merge: dict                                  # Merger.stats(): per node, shares and losses
    dropped: int                                 # merged frames the station could not keep up with
    authenticated: bool                          # node keys given: frames' MACs are checked
    rewound: dict[int, tuple[int, int]]          # nodes refused: {node: (newest boot, frame's boot)}
    listener_errors: dict[str, tuple[int, str]] = field(default_factory=dict)  # name -> (count, last)
    faults: dict[str, str] = field(default_factory=dict)  # station parts failing now: name -> what is wrong


@dataclass(frozen=True)
class AlarmState:
    """The alarm engine's picture: active alarms (oldest first, warnings last) and, per node,
    each rope's deviation and band (empty without the seal's friction lines), and each hoist
    node's standing status (`AlarmEngine.hoist_status`: the imbalance the seals can hide; shown
    as status, never as an alarm; empty without a band)."""

    time_s: float
    active: tuple[ActiveAlarm, ...]
    bands: dict[int, list[DeviationBand | None]]
    hidden: tuple[ActiveAlarm, ...] = ()      # shelved, out of service, suppressed by design
    hoist: dict[int, Any] = field(default_factory=dict)   # node -> HoistStatus (hidden_frac, text, ...)


class Listener:
    """Base of the station's listeners: override the messages you need (module docstring)."""

    name = "listener"
    publish: Callable[[Any], None] = staticmethod(lambda message: None)  # set by HoistPipeline.add

    def on_frame(self, item: Received, now_s: float) -> None:
        pass

    def on_event(self, event: AlarmEvent) -> None:
        pass

    def on_status(self, status: StationStatus) -> None:
        pass

    def on_alarms(self, state: AlarmState) -> None:
        pass

    def on_command(self, command: Command, now_s: float) -> CommandOutcome | None:
        """An operator action: the listener that carries it out returns its outcome."""
        return None

    def on_stop(self, status: StationStatus) -> None:
        pass

    def health(self) -> str | None:
        """None while this listener works; otherwise what is wrong (the station alarms on it)."""
        return None


# -- the spine ---------------------------------------------------------------------


class HoistPipeline:
    """One hoist's receivers -> `FrameHub` -> listeners, on one consumer thread (module docstring).

    `clock` is the listeners' time (alarm timing, status); `wall` stamps the station's own
    events and, through the hub, the frames' rx times; `wake` is set whenever the hub queues
    a frame or a command is submitted (a run loop waits on it).

    With keys and `resume_from` (a `Store` that already holds frames), the replay
    protection resumes from the log before any receiver is read (`resumed`): a
    frame at or below the last one logged for its node is a replay (or a duplicate
    of one of the last frames), as if the station had not stopped.
    """

    def __init__(self, keys: dict[int, bytes] | None = None, listeners: Iterable[Listener] = (),
                 clock: Callable[[], float] = time.monotonic, accept_rewound: Iterable[int] = (),
                 resume_from: Any = None, wall: Callable[[], float] = time.time,
                 wake: threading.Event | None = None) -> None:
        self.keys = keys or None
        self.hub = FrameHub(self.keys, clock=wall, accept_rewound=accept_rewound, wake=wake)
        self.clock = clock
        self.wall = wall          # the time the station's own events and the frames' rx times carry
        self.listeners: list[Listener] = []
        self.listener_errors: dict[str, tuple[int, str]] = {}
        self.resumed: dict[int, int] = {}               # node -> last seq logged, resumed from the store
        self._commands: "queue.SimpleQueue[tuple[Command, Ticket]]" = queue.SimpleQueue()
        self._asked: Command | None = None               # the command being handed to the listeners
        self._answer: CommandOutcome | None = None       # ... and the first outcome a listener returned
        self._pending: deque[Any] = deque()
        self._dispatching = False
        self._rebase_logged: dict[int, int] = {}        # node -> seq of the last baseline published
        self._errors_published: dict[str, int] = {}     # receiver -> callback_errors already published
        self._listener_errors_published: set[str] = set()
        self._errors_seen: dict[str, int] = {}          # listener -> errors counted at the last tick
        if resume_from is not None and self.keys:
            self.resumed = {n: seq for n, seq in resume_from.last_seqs().items() if n in self.keys}
            self.hub.seed(self.resumed, {n: resume_from.recent_frames(n, DUPLICATE_MEMORY) for n in self.resumed})
        for listener in listeners:
            self.add(listener)

    def add(self, listener: Listener) -> Listener:
        """Add a listener: it gets every message from now on, after those added before it."""
        listener.publish = self.publish
        self.listeners.append(listener)
        return listener

    # -- inputs ----------------------------------------------------------------------

    @property
    def decoders(self) -> dict[str, StreamDecoder]:
        return self.hub.decoders

    def add_port(self, url: str, name: str, **kw: Any) -> SerialReceiver:
        """Read receiver `name` from a serial port (pyserial URL); returns the SerialReceiver
        (not started)."""
        return self.hub.add_port(url, name, **kw)

    def feed(self, receiver: str, data: bytes) -> None:
        """Bytes of one receiver without a port (tests, captures), processed at once."""
        self.hub.feeder(receiver)(data)
        self.pump()

    def submit(self, command: Command) -> Ticket:
        """An operator action, from any thread; carried out at the next `pump`. Returns a
        future settled with its `CommandOutcome` then (on the station's thread)."""
        ticket: Ticket = Ticket()
        self._commands.put((command, ticket))
        if self.hub.wake is not None:
            self.hub.wake.set()
        return ticket

    def resumed_text(self) -> str | None:
        """One line saying where the replay protection resumed from (None: nothing logged before)."""
        if not self.resumed:
            return None
        mask = (1 << SEQ_COUNT_BITS) - 1
        nodes = ", ".join(f"node {n} at boot {seq >> SEQ_COUNT_BITS} count {seq & mask}"
                          for n, seq in sorted(self.resumed.items()))
        return f"resumed replay protection from the log: {nodes}"

    # -- the consumer thread -----------------------------------------------------------

    def pump(self) -> int:
        """Carry out submitted commands, then hand every merged frame the hub has queued to
        the listeners; return how many frames were taken from the queue."""
        while True:
            try:
                cmd, ticket = self._commands.get_nowait()
            except queue.Empty:
                break
            self._command(cmd, ticket)
        n = 0
        while True:
            item = self.hub.get(timeout=0)
            if item is None:
                break
            n += 1
            if item.is_new:
                self.publish(item)
            if item.rebased_from is not None:
                self._rebase(item)
        return n

    def tick(self) -> StationStatus:
        """Time passes: every listener gets the links' status (the alarm listener then its
        state). Call it a few times a second, frames or not."""
        status = self.status()
        self._errors_seen = {name: n for name, (n, _) in self.listener_errors.items()}
        self._publish_link_errors(status)
        self._listener_errors_published.clear()
        self.publish(status)
        return status

    def status(self) -> StationStatus:
        faults = {}
        for listener in self.listeners:
            try:
                why = listener.health()
            except Exception as e:  # a health check that fails is itself a fault
                why = f"health check failed: {type(e).__name__}: {e}"
            if why:
                faults[listener.name] = why
        for name, (n, last) in self.listener_errors.items():
            if n > self._errors_seen.get(name, 0):
                faults[name] = f"failed {n - self._errors_seen.get(name, 0)} time(s) since the last tick: {last}"
        return StationStatus(self.clock(), self.hub.status(), self.hub.merge_stats(), self.hub.dropped,
                             self.keys is not None, self.hub.rewound(), dict(self.listener_errors), faults)

    def close(self) -> None:
        """Stop the ports, hand on what is queued, and let every listener finish (`on_stop`)."""
        self.hub.stop()
        self.pump()
        status = self.status()
        for listener in self.listeners:
            self._call(listener, "on_stop", status)

    def publish(self, message: Any) -> None:
        """Hand `message` to every listener; a message published while listeners are being
        called is handed on after the current one, in order."""
        self._pending.append(message)
        if self._dispatching:
            return
        self._dispatching = True
        try:
            while self._pending:
                msg = self._pending.popleft()
                if isinstance(msg, (Received, Command)):
                    method, args = ("on_frame" if isinstance(msg, Received) else "on_command"), (msg, self.clock())
                else:
                    method, args = _METHOD[type(msg)], (msg,)
                for listener in self.listeners:
                    got = self._call(listener, method, *args)
                    if msg is self._asked and self._answer is None and isinstance(got, CommandOutcome):
                        self._answer = got
        finally:
            self._dispatching = False

    # -- internals ---------------------------------------------------------------------

    def _call(self, listener: Listener, method: str, *args: Any) -> Any:
        try:
            return getattr(listener, method)(*args)
        except Exception as e:  # one failing listener must not stop the alarms or the others
            name = listener.name
            n = self.listener_errors.get(name, (0, ""))[0] + 1
            text = f"{type(e).__name__}: {e}"
            self.listener_errors[name] = (n, text)
            if name not in self._listener_errors_published:
                self._listener_errors_published.add(name)
                self.publish(AlarmEvent(time_s=self.wall(), action="error", alarm=f"listener_error:{name}",
                                        kind="listener_error", count=n, message=f"{name} failed on {method}: {text}"))
            return None

    def _command(self, cmd: Command, ticket: Ticket) -> None:
        """Hand `cmd` to the listeners (the first outcome one returns is its outcome), or carry
        it out here (AcceptRewound); settle `ticket` with the outcome."""
        self._asked, self._answer = cmd, None
        try:
            self.publish(cmd)
            answer = self._answer
        finally:
            self._asked, self._answer = None, None
        if isinstance(cmd, AcceptRewound):
            answer = self._accept_rewound(cmd)
        settle(ticket, answer or CommandOutcome.refused(cmd, "nothing in the station carried it out"))

    def _accept_rewound(self, cmd: AcceptRewound) -> CommandOutcome:
        """Every receiver takes `cmd.node`'s next authenticated frame as its new baseline. Logged
        (who, when, which node) as an `accept` event: it decides whether frames are trusted."""
        node = cmd.node
        refused = self.hub.rewound().get(node)
        self.hub.accept_rewound(node)
        wall = self.wall()
        when = datetime.datetime.fromtimestamp(wall, datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
        was = f" (boot counter went back {refused[0]} -> {refused[1]})" if refused else ""
        self.publish(AlarmEvent(time_s=wall, action="accept", alarm=f"rewound:n{node}", kind="rewound", node=node,
                                newest_boot=refused[0] if refused else None, frame_boot=refused[1] if refused else None,
                                message=f"operator {cmd.operator} accepted node {node}{was} {cmd.how} at {when}"))
        return CommandOutcome.done(cmd)

    def _rebase(self, item: Received) -> None:
        """A receiver took an accepted node's frame of an older boot as its new baseline: a
        `rebase` event after that frame (the receivers of one node publish it once), so that a
        restart resumes the replay protection from this sequence."""
        f, prev = item.frame, item.rebased_from
        assert prev is not None
        if self._rebase_logged.get(f.node) == f.seq:
            return
        self._rebase_logged[f.node] = f.seq
        mask = (1 << SEQ_COUNT_BITS) - 1
        self.publish(AlarmEvent(
            time_s=self.wall(), action="rebase", alarm=f"rewound:n{f.node}", kind="rewound", node=f.node,
            seq=f.seq, prev_seq=prev, message=f"node {f.node}: boot {f.seq >> SEQ_COUNT_BITS} count {f.seq & mask} taken as its new baseline "
            f"(was boot {prev >> SEQ_COUNT_BITS} count {prev & mask}; receiver {item.receiver})"))

    def _publish_link_errors(self, status: StationStatus) -> None:
        """A `link_error` event for a receiver whose decoder or consumer raised since the last one."""
        for name, r in status.receivers.items():
            if r.callback_errors > self._errors_published.get(name, 0):
                self._errors_published[name] = r.callback_errors
                self.publish(AlarmEvent(
                    time_s=self.wall(), action="error", alarm=f"link_error:{name}", kind="link_error",
                    count=r.callback_errors, message=f"receiver {name}: {r.callback_errors} decoder/consumer errors "
                    f"(bytes lost), last: {r.last_callback_error}"))


_METHOD = {AlarmEvent: "on_event", StationStatus: "on_status", AlarmState: "on_alarms"}


# -- the station's own listeners ---------------------------------------------------


class AlarmListener(Listener):
    """The alarm engine on the station's messages: frames, ticks and acknowledgements in;
    events, and its state (after any event and at every tick), out."""

    name = "alarms"

    def __init__(self, settings: AlarmSettings | None = None) -> None:
        self.engine = AlarmEngine(settings)
        self._faulted: set[str] = set()   # station parts that have failed since the start

    def on_frame(self, item: Received, now_s: float) -> None:
        if self._publish(self.engine.update(item.frame, now_s)):
            self._publish_state(now_s)

    def on_status(self, status: StationStatus) -> None:
        now = status.time_s
        e = self.engine
        self._publish(e.tick(now))
        for name, r in status.receivers.items():
            if status.authenticated:
                self._publish(e.update_link(name, r.counts.mac_fail, r.counts.replayed, now))
            if r.url is not None:
                self._publish(e.update_receiver(name, r.url, r.connected, r.last_error, now))
        self._faulted |= set(status.faults)    # each tick until its alarm clears, too
        for source in sorted(self._faulted):
            why = status.faults.get(source)
            self._publish(e.update_fault(source, why is not None, why or f"{source} works again", now))
        self._publish_state(now)

    def on_command(self, command: Command, now_s: float) -> CommandOutcome | None:
        """An alarm command carried out by the engine: its outcome, a refusal also published as a
        `refused` event (the log's and every face's); None for a command not the engine's."""
        e, who = self.engine, f"{command.operator} ({command.via})"
        try:
            if isinstance(command, Acknowledge):
                events = e.ack(command.alarm, now_s, who)
            elif isinstance(command, Shelve):
                events = e.shelve(command.alarm, now_s, now_s + command.minutes * 60.0, command.reason, who)
            elif isinstance(command, Unshelve):
                events = e.unshelve(command.alarm, now_s, who)
            elif isinstance(command, RemoveFromService):
                events = e.remove_from_service(command.alarm, now_s, command.reason, who)
            elif isinstance(command, ReturnToService):
                events = e.return_to_service(command.alarm, now_s, who)
            else:
                return None
        except (KeyError, ValueError) as err:
            why = f"no alarm {command.target!r}" if isinstance(err, KeyError) else str(err)
            self.publish(AlarmEvent(time_s=now_s, action="refused", alarm=command.target, kind="command",
                                    message=f"{type(command).__name__} by {who} refused: {why}", operator=who))
            return CommandOutcome.refused(command, why)
        if self._publish(events):
            self._publish_state(now_s)
        return CommandOutcome.done(command)

    def _publish(self, events: list[AlarmEvent]) -> int:
        for e in events:
            self.publish(e)
        return len(events)

    def _publish_state(self, now_s: float) -> None:
        e = self.engine
        hoist = {}
        for n in e.nodes():
            st = e.hoist_status(n)
            if st is not None:
                hoist[n] = st
        self.publish(AlarmState(now_s, tuple(e.active()), {n: e.deviation_bands(n, now_s) for n in e.nodes()},
                                tuple(e.hidden()), hoist))


class StoreListener(Listener):
    """Frames, events and link figures into the SQLite log (`ropemon.station.store.Store`).

    A write that fails (disk full, I/O error) does not stop the station: what the log has not
    stored yet stays in memory, in order, and is written again every `RETRY_S` until the log
    takes it; meanwhile `health()` says so (STATION FAULT). Past `MAX_HELD` items the oldest
    frames are dropped and counted (events are kept). Frames held in memory are lost if the
    station itself stops.
    """

    name = "store"
    LINK_LOG_S = 10.0   # link statistics go to the log this often
    RETRY_S = 5.0       # a failing log is tried again this often
    MAX_HELD = 200_000  # items held while the log fails (about 5 h of frames at 10 frames/s)

    def __init__(self, store: Any, clock: Callable[[], float] = time.monotonic,
                 wall: Callable[[], float] = time.time) -> None:
        self.store = store
        self.clock = clock        # when to retry a failing log
        self.wall = wall          # the time of the link statistics' rows
        self._link_logged_s: float | None = None
        self._held: deque[tuple[str, tuple]] = deque()   # writes not yet committed, oldest first
        self.error: str | None = None                     # the last write error while failing
        self.dropped = 0                                  # frames dropped while the log failed
        self._retry_at = 0.0

    def on_frame(self, item: Received, now_s: float) -> None:
        self._write("add_frame", (item.receiver, item.frame, item.rx_time))

    def on_event(self, event: AlarmEvent) -> None:
        self._write("add_event", (event,))

    def on_status(self, status: StationStatus) -> None:
        if self.error is None:
            self._attempt(self.store.flush)
        else:
            self._retry()
        if self._link_logged_s is None or status.time_s - self._link_logged_s >= self.LINK_LOG_S:
            self.log_link_stats(status)
            self._link_logged_s = status.time_s

    def on_stop(self, status: StationStatus) -> None:
        self.log_link_stats(status)
        if self.error is not None:
            self._retry(force=True)
        self._attempt(self.store.commit)

    def health(self) -> str | None:
        if self.error is None:
            return None
        frames = sum(1 for op, _ in self._held if op == "add_frame")
        lost = f"; {self.dropped} older frames dropped" if self.dropped else ""
        return (f"cannot write {self.store.path}: {self.error}; {frames} frames and "
                f"{len(self._held) - frames} other records held in memory, retrying every {self.RETRY_S:.0f} s{lost}")

    def log_link_stats(self, status: StationStatus) -> None:
        """Decoder counts and merge shares of every receiver (`link_stats` table)."""
        t = self.wall()
        for name, r in status.receivers.items():
            self._write("add_link_stats", (t, name, r.counts.as_dict()))
            for node, st in status.merge.items():
                share = st["receivers"].get(name)
                if share is not None:
                    self._write("add_link_stats", (t, name, None, node, {
                        "delivered": share["delivered"], "share": share["share"],
                        "lost": st["lost"], "duplicates": st["duplicates"]}))

    # -- writing, and holding what the log could not take --------------------------------

    def _write(self, op: str, args: tuple) -> None:
        self._held.append((op, args))
        if len(self._held) > self.MAX_HELD:
            self._drop_oldest_frame()
        if self.error is None:
            self._attempt(getattr(self.store, op), *args)
        else:
            self._retry()

    def _attempt(self, fn: Callable[..., Any], *args: Any) -> bool:
        try:
            fn(*args)
        except sqlite3.Error as e:
            self._failed(e)
            return False
        if not self.store.db.in_transaction:   # committed: everything held is stored
            self._held.clear()
        return True

    def _failed(self, e: Exception) -> None:
        self.error = f"{type(e).__name__}: {e}"
        self._retry_at = self.clock() + self.RETRY_S
        try:
            self.store.rollback()
        except sqlite3.Error:
            pass  # the next retry rolls back again

    def _retry(self, force: bool = False) -> None:
        """Write everything held again, in order, in one transaction; commit."""
        if not force and self.clock() < self._retry_at:
            return
        items, stored = list(self._held), 0
        try:
            self.store.rollback()
            for k, (op, args) in enumerate(items):
                getattr(self.store, op)(*args)
                if not self.store.db.in_transaction:   # the store committed: these are stored
                    stored = k + 1
            self.store.commit()
        except sqlite3.Error as e:
            for _ in range(stored):
                self._held.popleft()
            self._failed(e)
            return
        self._held.clear()
        self.error = None

    def _drop_oldest_frame(self) -> None:
        for k, (op, _) in enumerate(self._held):
            if op == "add_frame":
                del self._held[k]
                self.dropped += 1
                return
        self._held.popleft()


def station_listeners(settings: AlarmSettings | None = None, store: Any = None,
                      *views: Listener, wall: Callable[[], float] = time.time) -> list[Listener]:
    """The hoist room's listeners in their order: the alarm engine, the log (when `store` is
    given; its link statistics stamped by `wall`), then the views."""
    out: list[Listener] = [AlarmListener(settings)]
    if store is not None:
        out.append(StoreListener(store, wall=wall))
    return out + list(views)
