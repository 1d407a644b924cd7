"""The Modbus face answers only the functions its map documents, and malformed traffic
from one peer does not flood `ropemon serve`'s log.

    pytest tests/scada/test_modbus_refusals.py -q -s -k flood    # prints the log lines per 1,000 bad frames
"""
from __future__ import annotations

import re
import signal
import socket
import struct
import subprocess
import sys
import time

import pytest

pytest.importorskip("pymodbus")

from pymodbus.client import ModbusTcpClient  # noqa: E402
from pymodbus.pdu.device import ModbusControlBlock  # noqa: E402

from ropemon.station import modbus as M  # noqa: E402
from ropemon.station.faces import start_faces  # noqa: E402
from scada_rig import Rig, free_port, wait, write_station  # noqa: E402

ILLEGAL_FUNCTION, ILLEGAL_VALUE = 1, 3


@pytest.fixture
def served(tmp_path):
    port = free_port()
    rig = Rig(tmp_path, 1, f"[modbus]\nport = {port}\nack_coil = true\n")
    faces = start_faces(rig.stations, rig.file)
    try:
        yield rig, faces[0], port
    finally:
        for f in faces:
            f.stop()
        rig.close()
        ModbusControlBlock().ListenOnly = False       # pymodbus's process-wide block, as it was


def adu(tid: int, pdu: bytes, unit: int = 1, pid: int = 0) -> bytes:
    return struct.pack(">HHHB", tid, pid, len(pdu) + 1, unit) + pdu


def ask(sock: socket.socket, tid: int, pdu: bytes) -> bytes:
    """One request, its response's PDU (the MBAP header checked)."""
    sock.sendall(adu(tid, pdu))
    head = _recv(sock, 7)
    rtid, pid, length, unit = struct.unpack(">HHHB", head)
    assert (rtid, pid, unit) == (tid, 0, 1)
    return _recv(sock, length - 1)


def _recv(sock: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        part = sock.recv(n - len(out))
        assert part, "the server closed the connection"
        out += part
    return out


#: requests of functions the map does not document, each with a well-formed body
UNDOCUMENTED = {
    "diagnostics: force listen only": bytes([8]) + struct.pack(">HH", 0x0004, 0),
    "diagnostics: restart communications": bytes([8]) + struct.pack(">HH", 0x0001, 0),
    "diagnostics: clear counters": bytes([8]) + struct.pack(">HH", 0x000A, 0),
    "diagnostics: return query data": bytes([8]) + struct.pack(">HH", 0x0000, 0x1234),
    "report server id": bytes([17]),
    "read device identification": bytes([43, 14, 1, 0]),
    "read exception status": bytes([7]),
    "comm event counter": bytes([11]),
    "read discrete inputs": bytes([2]) + struct.pack(">HH", 0, 1),
    "write register": bytes([6]) + struct.pack(">HH", M.HOIST_BASE, 7),
    "write registers": bytes([16]) + struct.pack(">HHBHH", M.HOIST_BASE, 2, 4, 7, 7),
    "mask write register": bytes([22]) + struct.pack(">HHH", M.HOIST_BASE, 0, 0xFFFF),
    "read/write registers": bytes([23]) + struct.pack(">HHHHBH", 0, 1, M.HOIST_BASE, 1, 2, 7),
    "read FIFO queue": bytes([24]) + struct.pack(">H", 0),
    "no such function": bytes([0x41]),
    "an exception code as a request": bytes([0x83, 2]),
}


def test_functions_the_map_does_not_document_are_refused_with_illegal_function(served):
    rig, face, port = served
    mcb = ModbusControlBlock()
    counters_before = dict(mcb.Counter.stat_data)
    with socket.create_connection(("127.0.0.1", port), timeout=3) as sock:
        header = ask(sock, 1, bytes([3]) + struct.pack(">HH", 0, 7))
        for tid, (what, pdu) in enumerate(UNDOCUMENTED.items(), start=2):
            answer = ask(sock, tid, pdu)
            assert answer == bytes([pdu[0] | 0x80, ILLEGAL_FUNCTION]), what
        # nothing changed: not in listen-only mode, counters untouched, the same registers
        # answered on the same connection, no acknowledgement, no register written
        assert not mcb.ListenOnly
        assert mcb.Counter.stat_data == counters_before
        assert ask(sock, 99, bytes([3]) + struct.pack(">HH", 0, 7)) == header
        assert ask(sock, 100, bytes([4]) + struct.pack(">HH", 0, 7))[1:] == header[1:]
    assert face.acks == 0 and face.register(M.HOIST_BASE) != 7


def test_the_documented_functions_are_answered_and_a_malformed_one_is_illegal_data_value(served):
    rig, face, port = served
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=3)
    try:
        assert client.connect()
        assert client.read_holding_registers(0, count=7).registers[0] == M.MAP_VERSION    # 3
        assert client.read_input_registers(0, count=7).registers[0] == M.MAP_VERSION      # 4
        assert client.read_coils(0, count=1).bits[0] is False                             # 1
        assert not client.write_coil(0, True).isError()                                   # 5 (ack_coil)
        assert not client.write_coils(0, [True]).isError()                                # 15
        r = client.diag_read_diagnostic_register()                                        # 8, pymodbus's own client
        assert r.isError() and r.exception_code == ILLEGAL_FUNCTION
        r = client.report_device_id()                                                     # 17
        assert r.isError() and r.exception_code == ILLEGAL_FUNCTION
        r = client.read_device_information()                                              # 43 / 14
        assert r.isError() and r.exception_code == ILLEGAL_FUNCTION
    finally:
        client.close()
    wait(lambda: face.acks == 2, 5, "the two coil writes")
    with socket.create_connection(("127.0.0.1", port), timeout=3) as sock:
        assert ask(sock, 1, bytes([3]) + struct.pack(">HH", 0, 0)) == bytes([0x83, ILLEGAL_VALUE])    # count 0
        assert ask(sock, 2, bytes([4, 0])) == bytes([0x84, ILLEGAL_VALUE])                           # too short


def bad_frames(n: int) -> tuple[list[bytes], list[bytes]]:
    """n malformed frames: (answered, one after the other on one connection), (one per connection:
    a wrong protocol id, which pymodbus answers with nothing)."""
    kinds = [lambda i: bytes([0x41 + i % 40]),                                  # no such function
             lambda i: bytes([8]) + struct.pack(">HH", i % 22, i),              # diagnostics
             lambda i: bytes([3, i & 0xFF]),                                    # a read cut short
             lambda i: bytes([0x83, i & 0xFF]),                                 # an exception as a request
             lambda i: bytes([4]) + struct.pack(">HH", i, 0)]                   # count 0
    answered = [adu(i, kinds[i % 5](i)) for i in range(n - n // 5)]
    unanswered = [adu(i, bytes([3, 0, 0, 0, 1]), pid=1 + i) for i in range(n // 5)]
    return answered, unanswered


def test_a_flood_of_malformed_frames_from_one_peer_is_a_few_lines_of_serves_log(tmp_path):
    """1,000 malformed frames from one peer into `ropemon serve` with [modbus]: its stderr
    (the journal) gets a few lines, one of them the count of those not shown."""
    port = free_port()
    station = write_station(tmp_path, 1, f"[modbus]\nport = {port}\n")
    err_path = tmp_path / "stderr.txt"
    answered, unanswered = bad_frames(1000)
    with open(err_path, "w") as err:
        p = subprocess.Popen([sys.executable, "-m", "ropemon.cli", "serve", str(station), "--quiet"],
                             stdout=subprocess.DEVNULL, stderr=err)
        try:
            wait(lambda: "Modbus TCP on" in err_path.read_text(), 20, "ropemon serve's Modbus face")
            start_lines = err_path.read_text().count("\n")
            with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
                for frame in answered:                         # one at a time, as a client does
                    tid = struct.unpack(">H", frame[:2])[0]
                    ask(sock, tid, frame[7:])                  # each answered (above: how)
            for frame in unanswered:
                with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
                    sock.sendall(frame)
            with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
                assert ask(sock, 1, bytes([3]) + struct.pack(">HH", 0, 1)) == bytes([3, 2, 0, M.MAP_VERSION])
            time.sleep(0.3)
        finally:
            p.send_signal(signal.SIGTERM)
            p.wait(timeout=20)
    text = err_path.read_text()
    lines = text.splitlines()[start_lines:]
    print(f"\n{len(answered) + len(unanswered)} malformed frames from one peer: {len(lines)} lines, "
          f"{sum(len(ln.encode()) + 1 for ln in lines):,} bytes on ropemon serve's stderr")
    assert p.returncode == 0, text[-2000:]
    assert len(lines) <= 8, "\n".join(lines[:40])
    counted = [int(m.group(1).replace(",", "")) for ln in lines
               if (m := re.search(r'(\S+) more like "Invalid Modbus protocol id: #" from 127\.0\.0\.1', ln))]
    assert len(counted) == 1 and len(unanswered) // 2 <= counted[0] <= len(unanswered) - 1, text
