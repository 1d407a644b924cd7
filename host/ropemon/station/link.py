"""Receiver serial links: a reader thread per port, reconnecting, and a hub that decodes and merges.

`SerialReceiver` reads one pyserial `serial_for_url` port (device path, loop://,
spy://, socket://, rfc2217://) in a thread and hands every chunk of bytes to
`on_bytes`. When the port fails (USB adapter unplugged, socket closed) it closes
it and retries with exponential backoff until the port is back. It does not use
serial.threaded.ReaderThread because that thread ends on the first error;
reconnection is the point here. Note that pyserial's socket:// open() flushes
bytes that arrived during the connect; the decoder resynchronises after them.

`FrameHub` wires receivers to one StreamDecoder each and one shared Merger, and
puts (receiver, frame, rx_time, is_new) on a queue for a single consumer thread
(`ropemon.station.pipeline.HoistPipeline`: alarms, store and views belong to that thread).
`FrameHub.seed` gives every decoder, also of receivers added later, the replay
state a restarted host resumes from (the log).
"""
from __future__ import annotations

import queue
import select
import threading
import time
from dataclasses import dataclass, replace
from typing import Callable, Iterable, Mapping

import serial
import serial.rs485
from serial.urlhandler import protocol_socket

from ropemon.station.decoder import DUPLICATE_MEMORY, DecodeCounts, StreamDecoder
from ropemon.station.merge import Merger
from ropemon.station.protocol import Frame

DEFAULT_BAUDRATE = 115200
READ_CHUNK = 4096   # bytes asked of a port per read when it does not say how many are waiting
#: With keys, a frame this many seqs behind the node's newest (from any receiver) is still taken
#: if no receiver delivered it yet (a late frame filling a gap); older ones are replays.
LATE_FRAMES = DUPLICATE_MEMORY


class SerialReceiver:
    """One receiver port read in a daemon thread; `on_bytes(data)` runs in that thread."""

    def __init__(self, url: str, name: str, on_bytes: Callable[[bytes], None], *, rs485: bool = False,
                 baudrate: int = DEFAULT_BAUDRATE, backoff_s: float = 0.1, backoff_max_s: float = 5.0,
                 read_timeout_s: float = 0.05):
        self.url = url
        self.name = name
        self.on_bytes = on_bytes
        self.rs485 = rs485
        self.baudrate = baudrate
        self.backoff_s = backoff_s
        self.backoff_max_s = backoff_max_s
        self.read_timeout_s = read_timeout_s
        self.connected = False
        self.reconnects = 0      # successful opens after the first
        self.opens = 0
        self.bytes_read = 0
        self.callback_errors = 0                     # exceptions of on_bytes (decoder or consumer)
        self.last_callback_error: str | None = None  # the latest of them, kept past port errors
        self.last_error: str | None = None
        self.serial: serial.SerialBase | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> "SerialReceiver":
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"rx-{self.name}", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self._close()

    def write(self, data: bytes) -> None:
        """Send bytes out of the port (loop:// tests, receiver commands)."""
        if self.serial is None:
            raise serial.SerialException(f"{self.name}: not connected")
        self.serial.write(data)

    def _open(self) -> serial.SerialBase:
        ser = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=self.read_timeout_s,
                                    do_not_open=True)
        if self.rs485:
            # Half duplex: the adapter's driver switches RTS around each transmission.
            ser.rs485_mode = serial.rs485.RS485Settings()
        ser.open()
        return ser

    def _close(self) -> None:
        ser, self.serial = self.serial, None
        self.connected = False
        if ser is not None:
            try:
                ser.close()
            except Exception:  # closing a vanished device can fail in many ways; it is gone anyway
                pass

    def _read(self, ser: serial.SerialBase) -> bytes:
        """What the port holds now (at least one byte, or nothing after the read timeout)."""
        if isinstance(ser, protocol_socket.Serial):
            # socket:// reports 1 byte waiting whatever it holds, and its read(n) drops the
            # bytes it had when the peer closes before n arrive: take what the socket has in
            # one recv, so a gateway's burst is read in chunks and nothing before a close is lost.
            sock = ser._socket
            ready, _, _ = select.select([sock], [], [], self.read_timeout_s)
            if not ready:
                return b""
            data = sock.recv(READ_CHUNK)
            if not data:
                raise serial.SerialException("socket disconnected")
            return data
        return ser.read(max(1, ser.in_waiting))

    def _run(self) -> None:
        delay = self.backoff_s
        while not self._stop.is_set():
            try:
                self.serial = self._open()
            except (serial.SerialException, OSError, ValueError) as e:
                self.last_error = f"open {self.url}: {e}"
                self._stop.wait(delay)
                delay = min(delay * 2, self.backoff_max_s)
                continue
            self.opens += 1
            if self.opens > 1:
                self.reconnects += 1
            self.connected = True
            delay = self.backoff_s
            try:
                ser = self.serial
                while not self._stop.is_set():
                    data = self._read(ser)
                    if data:
                        self.bytes_read += len(data)
                        try:
                            self.on_bytes(data)
                        except Exception as e:  # a consumer bug must not silently end the link
                            self.callback_errors += 1
                            self.last_error = self.last_callback_error = f"on_bytes: {type(e).__name__}: {e}"
            except (serial.SerialException, OSError) as e:
                self.last_error = f"read {self.url}: {e}"
            finally:
                self._close()


@dataclass(frozen=True)
class Received:
    receiver: str
    frame: Frame
    rx_time: float
    is_new: bool  # False: a duplicate of a frame another receiver (or this one) already delivered
    rebased_from: int | None = None  # the frame is this receiver's new baseline for its node (an
    #                                  operator-accepted rewind): the node's newest seq before it


@dataclass(frozen=True)
class ReceiverStatus:
    """One receiver as the hub saw it when asked: a copy, safe to keep and read in any thread."""

    name: str
    url: str | None                # None: fed directly (capture, test), no port
    connected: bool                # port open (a receiver without a port counts as connected)
    last_error: str | None         # why the port is not open, or the last read/consumer error
    bytes_read: int
    reconnects: int
    callback_errors: int           # exceptions of the decoder or consumer: bytes were lost
    last_callback_error: str | None
    counts: DecodeCounts           # the decoder's counts


class FrameHub:
    """Several receivers -> decoders -> one Merger -> a queue of `Received`.

    With keys, the hub is the one authority on each node's sequence over all receivers
    (`_current`): a frame older than the newest taken is a replay whichever receiver brings
    it, counted as `replayed` on that receiver. Each receiver's decoder is used only by the
    thread that feeds it. Other threads
    talk to the hub through its methods: `accept_rewound` leaves the decision in each
    decoder's inbox, applied by its own thread before its next bytes; `rewound`,
    `counts` and `status` return copies taken under the hub's lock after each chunk.
    `clock` stamps each frame's rx time; `wake`, when given, is set whenever frames are queued.
    """

    def __init__(self, keys: dict[int, bytes] | None = None, merger: Merger | None = None,
                 clock: Callable[[], float] = time.time, maxsize: int = 100000,
                 accept_rewound: Iterable[int] = (), wake: threading.Event | None = None):
        self.keys = keys
        self._accept_rewound = set(accept_rewound)  # operator decisions, for receivers added later
        self.merger = merger or Merger()
        self.clock = clock
        self.queue: "queue.Queue[Received]" = queue.Queue(maxsize)
        self.decoders: dict[str, StreamDecoder] = {}
        self.receivers: dict[str, SerialReceiver] = {}
        self.dropped = 0  # queue full: the consumer is not keeping up
        self._lock = threading.Lock()
        self._inbox: dict[str, list[int]] = {}           # receiver -> nodes accepted, not yet applied
        self._rewound: dict[str, dict[int, tuple[int, int]]] = {}
        self._counts: dict[str, DecodeCounts] = {}
        self._top: dict[int, int] = {}                   # node -> newest seq taken from any receiver
        self.wake = wake                                 # set when frames are queued (the consumer waits on it)
        self._seed: tuple[dict[int, int], dict[int, list[Frame]]] = ({}, {})

    def seed(self, last: Mapping[int, int], recent: Mapping[int, Iterable[Frame]] | None = None) -> None:
        """Replay state to resume from (`ReplayGuard.seed`): given to every receiver's
        decoder, also to those added later. Call before any bytes are fed."""
        self._seed = (dict(last), {n: list(fs) for n, fs in (recent or {}).items()})
        with self._lock:
            self._top.update(last)
        for dec in list(self.decoders.values()):
            dec.replay.seed(*self._seed)

    def feeder(self, name: str) -> Callable[[bytes], None]:
        """A callback that decodes bytes of receiver `name` (also usable without a serial port).
        Call it from one thread at a time (the receiver's)."""
        with self._lock:
            dec = self.decoders.get(name)
            if dec is None:
                dec = self.decoders[name] = StreamDecoder(self.keys, accept_rewound=self._accept_rewound)
                dec.replay.seed(*self._seed)
                self._inbox[name] = []
                self._rewound[name] = {}
                self._counts[name] = replace(dec.counts)

        def on_bytes(data: bytes) -> None:
            now = self.clock()
            with self._lock:
                accepted, self._inbox[name] = self._inbox[name], []
            for node in accepted:
                dec.replay.accept_rewound(node)
            frames = dec.feed(data)
            base = dec.take_rebased() if frames else {}
            with self._lock:
                for f in frames:
                    prev = base.get((f.node, f.seq)) if base else None
                    if self.keys is not None and not self._current(f, prev):
                        dec.counts.replayed += 1      # older than what another receiver brought
                        continue
                    item = Received(name, f, now, self.merger.add(name, f), prev)
                    try:
                        self.queue.put_nowait(item)
                    except queue.Full:
                        self.dropped += 1
                self._counts[name] = replace(dec.counts)
                if dec.replay.rewound != self._rewound[name]:
                    self._rewound[name] = dict(dec.replay.rewound)
            if frames and self.wake is not None:
                self.wake.set()
        return on_bytes

    def _current(self, f: Frame, rebased_from: int | None) -> bool:
        """The node-wide replay check over all receivers (with keys; under the lock): a frame is
        taken if it is the node's newest, an operator-accepted new baseline, a copy of one the
        merger remembers (a duplicate), or at most LATE_FRAMES behind the newest and not seen (a
        late frame filling a gap). Anything older is a replay, whichever receiver brings it."""
        top = self._top.get(f.node)
        if rebased_from is not None or top is None or f.seq > top:
            self._top[f.node] = f.seq
            return True
        return f.seq >= top - LATE_FRAMES or self.merger.has(f.node, f.seq)

    def add_port(self, url: str, name: str | None = None, **kw) -> SerialReceiver:
        name = name or f"rx{len(self.receivers) + 1}"
        if name in self.receivers:
            raise ValueError(f"receiver name {name!r} used twice")
        r = SerialReceiver(url, name, self.feeder(name), **kw)
        self.receivers[name] = r
        return r

    def start(self) -> None:
        for r in self.receivers.values():
            r.start()

    def stop(self) -> None:
        for r in self.receivers.values():
            r.stop()

    def rewound(self) -> dict[int, tuple[int, int]]:
        """Nodes refused because their boot counter went back: {node: (newest boot, its frame's boot)},
        over all receivers."""
        out: dict[int, tuple[int, int]] = {}
        with self._lock:
            for r in self._rewound.values():
                out.update(r)
        return out

    def accept_rewound(self, node: int) -> None:
        """Operator decision: every receiver takes `node`'s next authenticated frame as its new
        baseline (applied by each receiver's own thread before its next bytes). Receivers added
        later get it too."""
        with self._lock:
            self._accept_rewound.add(node)
            for inbox in self._inbox.values():
                inbox.append(node)

    def counts(self) -> dict[str, DecodeCounts]:
        """Each receiver's decode counts (copies)."""
        with self._lock:
            return dict(self._counts)

    def status(self) -> dict[str, ReceiverStatus]:
        """Every receiver, with or without a port, as it is now (copies)."""
        with self._lock:
            counts = dict(self._counts)
        out = {}
        for name in list(dict.fromkeys([*self.receivers, *counts])):
            r = self.receivers.get(name)
            c = counts.get(name, DecodeCounts())
            if r is None:
                out[name] = ReceiverStatus(name, None, True, None, 0, 0, 0, None, c)
            else:
                out[name] = ReceiverStatus(name, r.url, r.connected, r.last_error, r.bytes_read, r.reconnects,
                                           r.callback_errors, r.last_callback_error, c)
        return out

    def merge_stats(self) -> dict:
        with self._lock:
            return self.merger.stats()

    def get(self, timeout: float | None = None) -> Received | None:
        try:
            return self.queue.get(timeout=timeout)
        except queue.Empty:
            return None
