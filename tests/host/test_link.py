"""Serial links: loop://, a pty whose "adapter" is unplugged and plugged back, two receivers merged."""
from __future__ import annotations

import os
import pty
import threading
import time
import tty

from host_rig import frame_set
from ropemon.station.link import FrameHub, SerialReceiver


def wait_for(cond, timeout=5.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


class Sink:
    def __init__(self):
        self.data = bytearray()
        self.lock = threading.Lock()

    def __call__(self, b: bytes) -> None:
        with self.lock:
            self.data += b


def open_pty() -> tuple[int, str]:
    """A pty pair in raw mode: (master fd, slave path). The slave plays the USB adapter."""
    master, slave = pty.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    os.close(slave)
    return master, path


def test_loop_url_round_trip():
    sink = Sink()
    rx = SerialReceiver("loop://", "loop", sink).start()
    try:
        assert wait_for(lambda: rx.connected)
        payload = b"".join(w for _, w in frame_set(1, 20, False))
        rx.write(payload)
        assert wait_for(lambda: len(sink.data) == len(payload))
        assert bytes(sink.data) == payload
    finally:
        rx.stop()
    assert not rx.connected


def test_pty_reconnects_after_adapter_unplug(tmp_path):
    link = tmp_path / "ttyUSB-receiver"   # like /dev/serial/by-id/...: stable name, changing device
    m1, p1 = open_pty()
    os.symlink(p1, link)
    sink = Sink()
    rx = SerialReceiver(str(link), "pithead", sink, backoff_s=0.02, backoff_max_s=0.1).start()
    try:
        assert wait_for(lambda: rx.connected)
        os.write(m1, b"first\x00")
        assert wait_for(lambda: bytes(sink.data) == b"first\x00")
        # Unplug: the device goes away and its name with it.
        os.unlink(link)
        os.close(m1)
        assert wait_for(lambda: not rx.connected)
        time.sleep(0.2)  # a few failed reopen attempts
        assert rx.last_error is not None
        assert not rx.connected
        # Plug back in: a new device node under the same name.
        m2, p2 = open_pty()
        os.symlink(p2, link)
        assert wait_for(lambda: rx.connected)
        assert rx.reconnects == 1
        os.write(m2, b"second\x00")
        assert wait_for(lambda: bytes(sink.data) == b"first\x00second\x00")
        os.close(m2)
    finally:
        rx.stop()


def test_two_receivers_merged_through_the_hub():
    frames = frame_set(9, 60, False)
    hub = FrameHub()
    masters = {}
    for name in ("pithead", "midshaft"):
        m, path = open_pty()
        masters[name] = m
        hub.add_port(path, name)
    hub.start()
    try:
        assert wait_for(lambda: all(r.connected for r in hub.receivers.values()))
        # pithead hears the first 40 frames, midshaft the last 40: 20 heard by both
        os.write(masters["pithead"], b"".join(w for _, w in frames[:40]))
        os.write(masters["midshaft"], b"".join(w for _, w in frames[20:]))
        got = []
        assert wait_for(lambda: (got.extend(iter(lambda: hub.get(0), None)) or len(got) >= 80), timeout=10)
    finally:
        hub.stop()
        for m in masters.values():
            os.close(m)
    new = [(r.frame.node, r.frame.seq) for r in got if r.is_new]
    assert len(new) == 60 == len(set(new))
    assert sum(not r.is_new for r in got) == 20
    st = hub.merge_stats()
    assert sum(s["duplicates"] for s in st.values()) == 20
    for node, s in st.items():
        seqs = [seq for n, seq in new if n == node]
        assert s["lost"] == max(seqs) - min(seqs) + 1 - len(seqs)  # frame_set skips some seqs


def test_socket_url_reconnects_when_the_server_drops():
    import socket
    srv = socket.create_server(("127.0.0.1", 0))
    port = srv.getsockname()[1]
    done = threading.Event()

    def serve():
        for msg in (b"one\x00", b"two\x00"):
            conn, _ = srv.accept()
            time.sleep(0.2)  # pyserial's socket:// open() flushes whatever has already arrived
            conn.sendall(msg)
            if msg == b"two\x00":
                done.wait(5)
            conn.close()

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    sink = Sink()
    rx = SerialReceiver(f"socket://127.0.0.1:{port}", "tcp", sink, backoff_s=0.02).start()
    try:
        assert wait_for(lambda: bytes(sink.data) == b"one\x00two\x00"), (bytes(sink.data), rx.last_error)
        assert rx.reconnects == 1 and rx.connected
    finally:
        done.set()
        rx.stop()
        srv.close()


def test_rs485_mode_refused_by_the_port_is_reported_not_fatal():
    m, path = open_pty()
    rx = SerialReceiver(path, "rs485", Sink(), rs485=True, backoff_s=0.02).start()
    try:
        assert wait_for(lambda: rx.last_error is not None)
        assert not rx.connected and "RS485" in rx.last_error
    finally:
        rx.stop()
        os.close(m)


def test_a_failing_consumer_does_not_end_the_link():
    got = []

    def consumer(b: bytes) -> None:
        if b"!" in b:
            raise RuntimeError("consumer bug")
        got.append(b)

    rx = SerialReceiver("loop://", "loop", consumer).start()
    try:
        assert wait_for(lambda: rx.connected)
        rx.write(b"!")
        assert wait_for(lambda: rx.callback_errors == 1)
        rx.write(b"good\x00")
        assert wait_for(lambda: b"".join(got) == b"good\x00")
        assert "consumer bug" in rx.last_error and rx.connected
    finally:
        rx.stop()


def test_hub_passes_the_operator_acceptance_to_every_receiver():
    from host_rig import KEYS
    from ropemon.station.decoder import SEQ_COUNT_BITS
    from ropemon.station.protocol import encode_frame

    def w(boot, k):
        return encode_frame(node=1, seq=(boot << SEQ_COUNT_BITS) | k, ropes=[(1, 1, 1, 1)], key=KEYS[1])[1]

    hub = FrameHub(KEYS)
    pit, mid = hub.feeder("pithead"), hub.feeder("mid-shaft")
    pit(w(7, 0) + w(7, 1))
    mid(w(7, 1))
    pit(w(0, 0))
    mid(w(0, 0))
    assert hub.rewound() == {1: (7, 0)}
    assert all(d.counts.rewound == 1 for d in hub.decoders.values())
    hub.accept_rewound(1)
    pit(w(0, 1))
    mid(w(0, 1))
    assert hub.rewound() == {}
    got = [hub.get(0) for _ in range(hub.queue.qsize())]
    assert [(r.receiver, r.frame.seq & 0xFFFFF, r.is_new) for r in got][-2:] == [
        ("pithead", 1, True), ("mid-shaft", 1, False)]
    # Given up front it reaches receivers created later.
    pre = FrameHub(KEYS, accept_rewound=[1])
    assert pre.feeder("rx")(b"") is None and pre.decoders["rx"].replay._rebase == {1}


def test_a_decoder_error_is_shown_on_the_link_line_and_logged_once(tmp_path):
    """SerialReceiver survives an exception of its consumer; the monitor must not hide it:
    the link line shows the count and the last error, the log gets one event per new error."""
    from ropemon.station.monitor import MonitorView
    from ropemon.station.nodefigures import NodeFigures
    from ropemon.station.pipeline import HoistPipeline, station_listeners
    from ropemon.station.store import Store

    def decoder_bug(data: bytes) -> None:
        raise RuntimeError("decoder bug")

    with Store(tmp_path / "log.db") as store:
        view = MonitorView(NodeFigures())
        session = HoistPipeline(None, station_listeners(None, store, view))
        rx = session.add_port("loop://", "pithead")
        session.tick()
        assert "ERRORS" not in "".join(fig for _, fig in view.link_rows)  # none: nothing shown
        rx.on_bytes = decoder_bug
        rx.start()
        try:
            assert wait_for(lambda: rx.connected)
            rx.write(b"x")                 # one byte: one read, one error
            assert wait_for(lambda: rx.callback_errors == 1)
            session.tick()
            row = dict(view.link_rows)["pithead"]
            assert "ERRORS 1: on_bytes: RuntimeError: decoder bug" in row
            session.tick()                 # no new error since: no second event
            ev = [e for e in store.events() if e["kind"] == "link_error"]
            assert len(ev) == 1 and ev[0]["alarm"] == "link_error:pithead" and ev[0]["value"] == 1
            assert "decoder bug" in ev[0]["message"]
        finally:
            rx.stop()


def test_a_socket_receiver_reads_a_burst_in_large_chunks_not_byte_by_byte():
    """socket:// (a serial-to-Ethernet gateway) reports one byte waiting whatever it holds: the
    receiver must still take a burst in chunks, or a backlog drains at a few KiB/s."""
    import socket
    import threading

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]
    chunks: list[int] = []
    rx = SerialReceiver(f"socket://127.0.0.1:{port}", "gateway", lambda d: chunks.append(len(d)))
    burst = bytes(range(256)) * 1024                     # 256 KiB
    conns = []

    def serve():
        c, _ = srv.accept()
        conns.append(c)

    t = threading.Thread(target=serve)
    t.start()
    rx.start()
    try:
        t.join(5)
        assert wait_for(lambda: rx.connected)
        time.sleep(0.2)                                  # pyserial flushes input on open
        conns[0].sendall(burst)
        assert wait_for(lambda: sum(chunks) >= len(burst), timeout=10)
        assert sum(chunks) == len(burst)
        assert len(chunks) < len(burst) // 1024          # on average at least 1 KiB per read
    finally:
        rx.stop()
        for c in conns:
            c.close()
        srv.close()
