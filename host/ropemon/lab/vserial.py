"""Virtual serial ports: pty pairs that stand in for the receivers' RS485 adapters.

The host opens `VirtualPort.port` (the pty's slave path, e.g. /dev/pts/7) with
pyserial exactly as it would open /dev/ttyUSB0; the simulation writes the
receiver's bytes into the master side. `play` paces deliveries in time.
pyserial discards pending input when it opens a port, so write only after the
reader has opened it (`SerialReceiver.connected`).
"""
from __future__ import annotations

import os
import pty
import select
import threading
import time
import tty
from typing import Callable, Iterable


class VirtualPort:
    """One pty pair. We keep the slave fd open ourselves so that the line stays
    up while the host closes and reopens it (as after a USB replug)."""

    def __init__(self, name: str = "") -> None:
        self.name = name
        self.master_fd, self._slave_fd = pty.openpty()
        tty.setraw(self._slave_fd)  # no echo, no line editing, no CR/LF mapping: a binary line
        self.port = os.ttyname(self._slave_fd)
        os.set_blocking(self.master_fd, False)
        self.bytes_written = 0
        self._closed = False

    def write(self, data: bytes, timeout_s: float = 5.0) -> None:
        """Write all of `data`; raise TimeoutError when the reader stops reading."""
        view = memoryview(data)
        deadline = time.monotonic() + timeout_s
        while view:
            try:
                n = os.write(self.master_fd, view)
            except BlockingIOError:
                n = 0
            if n:
                view = view[n:]
                self.bytes_written += n
                continue
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"{self.name or self.port}: reader not draining the pty")
            select.select([], [self.master_fd], [], min(left, 0.05))

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for fd in (self.master_fd, self._slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> "VirtualPort":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def play(
    port: VirtualPort,
    events: Iterable[tuple[float, bytes]],
    speed: float = 1.0,
    stop: threading.Event | None = None,
    clock: Callable[[], float] = time.monotonic,
    t0: float | None = None,
) -> int:
    """Write (time s, bytes) events to `port`, `speed` times faster than real time.

    `speed` <= 0 writes as fast as the reader drains. Returns bytes written.
    Events are written in order; their times must not decrease.
    """
    start = clock() if t0 is None else t0
    first: float | None = None
    total = 0
    for t_s, data in events:
        if stop is not None and stop.is_set():
            break
        if first is None:
            first = t_s
        if speed > 0:
            wait = start + (t_s - first) / speed - clock()
            if wait > 0:
                if stop is not None:
                    if stop.wait(wait):
                        break
                else:
                    time.sleep(wait)
        port.write(data)
        total += len(data)
    return total


class Player(threading.Thread):
    """`play` in a daemon thread; `.error` holds what stopped it, if anything."""

    def __init__(self, port: VirtualPort, events: list[tuple[float, bytes]], speed: float,
                 t0: float | None = None) -> None:
        super().__init__(name=f"play-{port.name}", daemon=True)
        self.port, self.events, self.speed, self.t0 = port, events, speed, t0
        self.stop_event = threading.Event()
        self.error: BaseException | None = None
        self.written = 0

    def run(self) -> None:
        try:
            self.written = play(self.port, self.events, self.speed, self.stop_event, t0=self.t0)
        except BaseException as e:  # reported by the caller, never lost
            self.error = e

    def stop(self) -> None:
        self.stop_event.set()
