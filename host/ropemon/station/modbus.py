"""The Modbus TCP face: every hoist's values in a versioned register map (docs/integration.md).

    [modbus]
    bind = "127.0.0.1"       # the address to listen on ("0.0.0.0": every interface)
    port = 5020              # 502 needs root or CAP_NET_BIND_SERVICE; 0: any free port
    ack_coil = false         # true: writing 1 to coil h acknowledges hoist h's alarms

The server answers functions 1 (read coils), 3 and 4 (read registers), 5 and 15 (write
coils) and no other: any other function code (diagnostics 8, report server id 17, device
identification 43, register writes, ...) decodes to a refusal, exception 1 ILLEGAL
FUNCTION, which changes nothing; a request of those five that does not decode (a count
out of range, too short) gets exception 3 ILLEGAL DATA VALUE. Neither is logged.

Registers (function 3 holding or 4 input: the same map, read-only): map header at 0,
hoist h's block at `HOIST_BASE + h * HOIST_STRIDE` (hoists in the station file's order).
Values are 16-bit registers; a 32-bit value spans two, high word first (big-endian words,
"ABCD"); signed values are two's complement. The map's layout is `MAP_VERSION`; a reader
checks register 0 first. Version 2 is version 1 with registers added where version 1 had
none (the pistons, the standing status, the equalizer's alarm bits): every register of
version 1 keeps its address and its meaning.

The listener (`ModbusValues`, one per hoist, on the station's thread) builds the hoist's
block and swaps in a new tuple; the server (pymodbus, its own asyncio loop in its own
thread) reads whichever tuple is current. The station never waits for the server.
A coil write (with ack_coil) goes through the station's command path
(`Station.submit(hoist, Acknowledge("modbus <peer>", "modbus"))`); the write is answered at
once, and the face logs a refusal from the command's outcome when the station carries it out.
"""
from __future__ import annotations

import asyncio
import contextvars
import logging
import struct
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.exceptions import ModbusException
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.server import ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler

from ropemon.station.tomlfields import Table
from ropemon.station import logsummary
from ropemon.station.faces import StationView
from ropemon.station.pipeline import Acknowledge
from ropemon.station.scadavalues import ALARM_KINDS, EQUALIZER_KINDS, HoistValues, NodeValues
from ropemon.station.stationfile import StationConfigError

MAP_VERSION = 2
FUNCTIONS = (1, 3, 4, 5, 15)   # the function codes answered (docs/integration.md); any other: ILLEGAL FUNCTION
HOIST_BASE = 100            # hoist 0's block
HOIST_STRIDE = 100          # registers per hoist block
MAX_HOISTS = 64
NODE_BASE = 20              # node k's sub-block within the hoist block: NODE_BASE + k * NODE_STRIDE
NODE_STRIDE = 40
MAX_NODES = 2               # cage nodes per hoist in the map (a hoist of more is refused)
ROPES = 4
ROPE_BASE = 12              # within the node sub-block: rope r at ROPE_BASE + 2 * r (tension, deviation)
I16_NONE = -32768           # an int16 value not available
I32_NONE = -(1 << 31)       # an int32 value not available
AGE_NONE = 0xFFFF           # frame age: never, or 6553.5 s and more

# hoist header offsets
HB, STATUS, PRESENT, UNACKED, AGE, NODES, FRAMES = 0, 1, 2, 4, 6, 7, 8
EQ_PRESENT, EQ_UNACKED = 9, 11          # version 2: the EQUALIZER_KINDS words (uint32 each)
# status bits
ST_VOUCHED, ST_ALARM, ST_UNACKED, ST_ALL_HEARD, ST_ACK_COIL = 1, 2, 4, 8, 16
# node sub-block offsets
N_ID, N_AGE, N_STATUS, N_FAULTS, N_SUM, N_DEPTH, N_SPEED, N_BATTERY, N_OIL, N_ROPES = 0, 1, 2, 3, 4, 6, 8, 9, 10, 11
N_SEQ = ROPE_BASE + 2 * ROPES   # 20..21: the frame's sequence number (uint32)
# version 2, node sub-block: rope r's piston position (int16, 0.1 mm) at N_POS + r, the frame's
# stroke mask, its layout version, the hidden imbalance (int16, 0.01 %), rope r's stroke
# (uint16, 0.1 mm) at N_STROKE + r, the stroke margin (uint16, 0.1 mm)
N_POS, N_STROKE_MASK, N_VERSION, N_HIDDEN, N_STROKE, N_MARGIN = 22, 26, 27, 28, 29, 33

log = logging.getLogger(__name__)
_PEER: contextvars.ContextVar[str] = contextvars.ContextVar("modbus_peer", default="?")


def _i16(v: int | None) -> int:
    return (I16_NONE if v is None else max(-32767, min(32767, v))) & 0xFFFF


def _i32(words: list[int], at: int, v: int | None) -> None:
    u = (I32_NONE if v is None else max(-(1 << 31) + 1, min((1 << 31) - 1, v))) & 0xFFFFFFFF
    words[at], words[at + 1] = u >> 16, u & 0xFFFF


def _u01mm(m: float | None) -> int:
    """A length in m as uint16 0.1 mm (0: unknown)."""
    return 0 if m is None or not m > 0 else min(0xFFFF, round(m * 10_000))


def _age(now_s: float, then_s: float | None) -> int:
    if then_s is None:
        return AGE_NONE
    return min(AGE_NONE, max(0, round((now_s - then_s) * 10)))


class ModbusValues(HoistValues):
    """One hoist's register block, rebuilt on the station's thread and swapped in whole."""

    name = "modbus"

    def __init__(self, face: "ModbusFace", index: int, hoist: str, nodes: Sequence[int],
                 stroke_m: Sequence[float] = (), margin_m: float | None = None) -> None:
        super().__init__(hoist, nodes)
        self.face, self.index = face, index
        self.frames = 0
        self.words = [0] * HOIST_STRIDE
        self.words[NODES] = len(self.nodes)
        for k, n in enumerate(self.nodes):
            base = NODE_BASE + k * NODE_STRIDE
            self.words[base + N_ID] = n
            self.words[base + N_AGE] = AGE_NONE
            self._node_none(base)
            for r in range(ROPES):
                self.words[base + N_STROKE + r] = _u01mm(stroke_m[r] if r < len(stroke_m) else None)
            self.words[base + N_MARGIN] = _u01mm(margin_m)
        self.words[AGE] = AGE_NONE
        face.blocks[index] = tuple(self.words)

    def _node_none(self, base: int) -> None:
        w = self.words
        _i32(w, base + N_SUM, None)
        _i32(w, base + N_DEPTH, None)
        w[base + N_SPEED] = w[base + N_OIL] = _i16(None)
        for r in range(ROPES):
            w[base + ROPE_BASE + 2 * r] = w[base + ROPE_BASE + 2 * r + 1] = _i16(None)
            w[base + N_POS + r] = _i16(None)
        w[base + N_HIDDEN] = _i16(None)

    def changed(self, what: str, v: NodeValues | None) -> None:
        w = self.words
        if v is not None:
            self.frames += 1
            w[FRAMES] = self.frames & 0xFFFF
            k = self.nodes.index(v.node) if v.node in self.nodes else None
            if k is not None:
                self._node(NODE_BASE + k * NODE_STRIDE, v)
        now = self.station_s
        newest = max((x.station_s for x in self.latest.values()), default=None)
        if what == "tick":
            w[AGE] = _age(now, newest)
            for k, n in enumerate(self.nodes):
                x = self.latest.get(n)
                w[NODE_BASE + k * NODE_STRIDE + N_AGE] = _age(now, x.station_s if x else None)
        elif v is not None:
            w[AGE] = 0
        w[HB] = self.heartbeat
        w[PRESENT], w[PRESENT + 1] = self.present_bits >> 16, self.present_bits & 0xFFFF
        w[UNACKED], w[UNACKED + 1] = self.unacked_bits >> 16, self.unacked_bits & 0xFFFF
        w[EQ_PRESENT], w[EQ_PRESENT + 1] = self.present_eq >> 16, self.present_eq & 0xFFFF
        w[EQ_UNACKED], w[EQ_UNACKED + 1] = self.unacked_eq >> 16, self.unacked_eq & 0xFFFF
        for k, n in enumerate(self.nodes):
            hidden = self.standing[n].hidden_frac
            w[NODE_BASE + k * NODE_STRIDE + N_HIDDEN] = _i16(None if hidden is None else round(hidden * 10000))
        w[STATUS] = ((ST_VOUCHED if self.vouched else 0) | (ST_ALARM if self.present_bits else 0)
                     | (ST_UNACKED if self.unacked_bits else 0)
                     | (ST_ALL_HEARD if all(n in self.latest for n in self.nodes) else 0)
                     | (ST_ACK_COIL if self.face.ack_coil else 0))
        self.face.blocks[self.index] = tuple(w)

    def _node(self, base: int, v: NodeValues) -> None:
        w = self.words
        w[base + N_AGE] = 0
        w[base + N_STATUS] = v.status & 0xFFFF
        w[base + N_FAULTS] = v.fault_mask & 0xFFFF
        _i32(w, base + N_SUM, v.sum_dan)
        _i32(w, base + N_DEPTH, v.depth_mm)
        w[base + N_SPEED] = _i16(v.speed_mm_s)
        w[base + N_BATTERY] = max(0, min(0xFFFF, v.battery_mv))
        w[base + N_OIL] = _i16(None if v.oil_temp_c is None else round(v.oil_temp_c * 100))
        w[base + N_ROPES] = len(v.ropes)
        for r in range(ROPES):
            rope = v.ropes[r] if r < len(v.ropes) else None
            w[base + ROPE_BASE + 2 * r] = _i16(rope.tension_dan if rope else None)
            dev = rope.deviation if rope else None
            w[base + ROPE_BASE + 2 * r + 1] = _i16(None if dev is None else round(dev * 10000))
        _i32(w, base + N_SEQ, v.seq & 0x7FFFFFFF)
        for r in range(ROPES):
            rope = v.ropes[r] if r < len(v.ropes) else None
            w[base + N_POS + r] = _i16(rope.pos_01mm if rope else None)
        w[base + N_STROKE_MASK] = v.stroke_mask & 0xFF
        w[base + N_VERSION] = v.version & 0xFFFF


def _log_refused(hoist: str, ticket: Any) -> None:
    """The station refused the face's acknowledgement (its outcome, on the station's thread)."""
    out = None if ticket.cancelled() or ticket.exception() is not None else ticket.result()
    if out is not None and not out.ok:
        who = out.command.operator if out.command is not None else "?"
        log.warning("hoist %s: acknowledge by %s refused: %s", hoist, who, out.reason)


class _Context(ModbusServerContext):
    """The register map as pymodbus's datastore: reads from the current tuples, coil writes
    as acknowledgements. Runs on the server's loop."""

    def __init__(self, face: "ModbusFace") -> None:  # pylint: disable=super-init-not-called
        self.face = face
        self.old_simulator = True     # pymodbus then calls this object's async_getValues/setValues
        self.simdevices = []
        self._devices = {}

    def device_ids(self) -> list[int]:
        return [0]

    async def async_getValues(self, device_id: int, func_code: int, address: int, count: int = 1):
        f = self.face
        if func_code in (3, 4):
            if address < 0 or count < 1 or address + count > f.size:
                return ExcCodes.ILLEGAL_ADDRESS
            return [f.register(a) for a in range(address, address + count)]
        if func_code in (1, 5, 15):
            if address < 0 or address + count > len(f.blocks):
                return ExcCodes.ILLEGAL_ADDRESS
            return [bool(f.blocks[h][UNACKED] or f.blocks[h][UNACKED + 1]) for h in range(address, address + count)]
        return ExcCodes.ILLEGAL_FUNCTION

    async def async_setValues(self, device_id: int, func_code: int, address: int, values: Sequence[Any]):
        f = self.face
        if func_code not in (5, 15) or not f.ack_coil:
            return ExcCodes.ILLEGAL_FUNCTION
        if address < 0 or address + len(values) > len(f.blocks):
            return ExcCodes.ILLEGAL_ADDRESS
        for h, v in zip(range(address, address + len(values)), values):
            if v:
                f.acknowledge(h, _PEER.get())
        return None


class _Refusal(ModbusPDU):
    """A request the server does not carry out: its answer is the exception `code`."""

    def __init__(self, function_code: int, code: int) -> None:
        super().__init__()
        self.function_code, self.code = function_code, code

    async def datastore_update(self, context: Any, device_id: int) -> ModbusPDU:
        return ExceptionResponse(self.function_code, self.code)


class _Decoder(DecodePDU):
    """pymodbus's request decoder with only `FUNCTIONS`: any other function code decodes to a
    `_Refusal` (ILLEGAL FUNCTION); a request of one of them that does not decode, to ILLEGAL
    DATA VALUE (pymodbus would answer both as function 0 and log each)."""

    def __init__(self) -> None:
        super().__init__(True)
        self.pdu_table = {fc: DecodePDU.pdu_table[fc] for fc in FUNCTIONS}

    def decode(self, frame: bytes) -> ModbusPDU | None:
        fc = frame[0]
        if fc not in self.pdu_table:
            return _Refusal(fc, ExcCodes.ILLEGAL_FUNCTION)
        pdu = self.pdu_table[fc][0]()
        try:
            pdu.decode(frame[1:])
        except (ModbusException, ValueError, IndexError, struct.error):
            return _Refusal(fc, ExcCodes.ILLEGAL_VALUE)
        return pdu


class _Handler(ServerRequestHandler):
    """One connection: its peer named for the ack's operator and the log (`logsummary.PEER`)."""

    _peer: tuple[str, str] | None = None

    def peer(self) -> tuple[str, str]:
        if self._peer is None:
            p = self.transport.get_extra_info("peername") if self.transport is not None else None
            if not p:
                return "?", ""
            self._peer = f"{p[0]}:{p[1]}", str(p[0])
        return self._peer

    def callback_data(self, data: bytes, addr: tuple | None = None) -> int:
        token = logsummary.PEER.set(self.peer()[1])
        try:
            return super().callback_data(data, addr)
        finally:
            logsummary.PEER.reset(token)

    async def handle_request(self):
        full, host = self.peer()
        _PEER.set(full)
        logsummary.PEER.set(host)
        await super().handle_request()


class _Server(ModbusTcpServer):
    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.decoder = _Decoder()      # every connection's framer decodes with it

    def callback_new_connection(self):
        return _Handler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


class ModbusFace:
    """The server thread and the map's blocks (module docstring)."""

    def __init__(self, view: StationView, config: ModbusConfig) -> None:
        self.station = view
        self.hoist_ids = list(view.hoists)
        self.bind, self.port, self.ack_coil = config.bind, config.port, config.ack_coil
        self.blocks: list[tuple[int, ...]] = [(0,) * HOIST_STRIDE for _ in self.hoist_ids]
        self.header = (MAP_VERSION, len(self.hoist_ids), HOIST_BASE, HOIST_STRIDE, MAX_NODES, ROPES,
                       1 if self.ack_coil else 0)
        self.size = HOIST_BASE + HOIST_STRIDE * len(self.hoist_ids)
        self.acks = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: _Server | None = None
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    def register(self, address: int) -> int:
        if address < HOIST_BASE:
            return self.header[address] if address < len(self.header) else 0
        h, off = divmod(address - HOIST_BASE, HOIST_STRIDE)
        return self.blocks[h][off]

    def acknowledge(self, index: int, peer: str) -> None:
        self.acks += 1
        hoist = self.hoist_ids[index]
        ticket = self.station.submit(hoist, Acknowledge(f"modbus {peer}", "modbus"))
        ticket.add_done_callback(lambda t: _log_refused(hoist, t))

    # -- the server's thread -----------------------------------------------------------------

    def start(self) -> None:
        ready = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(ready,), name="modbus", daemon=True)
        self._thread.start()
        ready.wait(10.0)
        if self._error is not None:
            raise self._error
        if self._server is None:
            raise RuntimeError("the Modbus server did not start within 10 s")

    def _run(self, ready: threading.Event) -> None:
        loop = self._loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)

        async def listen() -> _Server:
            server = _Server(_Context(self), address=(self.bind, self.port))
            await server.serve_forever(background=True)
            return server

        try:
            self._server = loop.run_until_complete(listen())
            sockets = getattr(self._server.transport, "sockets", None)
            if sockets:
                self.port = sockets[0].getsockname()[1]
        except BaseException as e:  # noqa: BLE001 - handed to start()
            self._error = OSError(f"[modbus]: cannot listen on {self.bind}:{self.port}: {e}")
            ready.set()
            loop.close()
            return
        ready.set()
        try:
            loop.run_forever()
        finally:
            loop.close()

    def stop(self) -> None:
        loop, server = self._loop, self._server
        if loop is None or server is None or self._thread is None:
            return
        try:
            asyncio.run_coroutine_threadsafe(server.shutdown(), loop).result(5.0)
        except Exception:  # noqa: BLE001 - stopping anyway
            log.exception("modbus: shutdown failed")
        loop.call_soon_threadsafe(loop.stop)
        self._thread.join(5.0)
        self._server = None

    def describe(self) -> str:
        ack = ", coil h acknowledges hoist h" if self.ack_coil else ", read-only"
        return (f"Modbus TCP on {self.bind}:{self.port}: map version {MAP_VERSION}, "
                f"{len(self.hoist_ids)} hoist block(s) at {HOIST_BASE} + {HOIST_STRIDE} h{ack}")


@dataclass(frozen=True)
class ModbusConfig:
    """The [modbus] table, checked (`parse_table`)."""

    bind: str = "127.0.0.1"
    port: int = 5020          # 0: any free port
    ack_coil: bool = False


def parse_table(table: Any, base: Path | None = None) -> ModbusConfig:
    """The [modbus] table, checked; StationConfigError names the field (`base`: no paths here)."""
    t = Table(table, "modbus", StationConfigError)
    out = ModbusConfig(t.string("bind", "127.0.0.1"), t.integer("port", 5020, lo=0, hi=65535),
                       t.boolean("ack_coil", False))
    t.finish()
    return out


def start(view: StationView, config: ModbusConfig) -> ModbusFace:
    """Add one `ModbusValues` per hoist, start the server (the faces contract, `ropemon.station.faces`)."""
    if len(view.hoists) > MAX_HOISTS:
        raise StationConfigError(f"modbus: the map holds {MAX_HOISTS} hoists, the station file has "
                                 f"{len(view.hoists)}")
    face = ModbusFace(view, config)
    for h in view.hoists.values():
        nodes = sorted(h.keys)
        if len(nodes) > MAX_NODES:
            raise StationConfigError(f"modbus: hoist {h.id} has {len(nodes)} nodes; the map holds {MAX_NODES} per hoist")
    index = {hid: i for i, hid in enumerate(face.hoist_ids)}
    view.add_listeners(lambda h: ModbusValues(face, index[h.id], h.id, sorted(h.keys),
                                              list(getattr(h.figures, "stroke_m", None) or ()),
                                              getattr(h.figures, "stroke_margin_m", None)))
    face.start()
    return face


__all__ = ["ALARM_KINDS", "EQUALIZER_KINDS", "MAP_VERSION", "ModbusConfig", "ModbusFace", "parse_table", "start"]
