"""The Modbus TCP face read and written by a pymodbus client: the map, the heartbeat, the ack coil."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

pytest.importorskip("pymodbus")

from pymodbus.client import ModbusTcpClient  # noqa: E402

from ropemon.station import modbus as M  # noqa: E402
from ropemon.station.faces import start_faces  # noqa: E402
from ropemon.station.scadavalues import ALARM_KINDS, EQUALIZER_KINDS  # noqa: E402
from ropemon.station.stationfile import StationConfigError  # noqa: E402
from scada_rig import Rig, free_port  # noqa: E402


def s16(u: int) -> int:
    return u - 0x10000 if u & 0x8000 else u


def s32(hi: int, lo: int) -> int:
    u = hi << 16 | lo
    return u - (1 << 32) if u & 0x80000000 else u


@pytest.fixture
def served(tmp_path):
    made = []

    def make(n_hoists: int = 2, extra: str = ""):
        port = free_port()
        rig = Rig(tmp_path, n_hoists, f"[modbus]\nport = {port}\n{extra}")
        faces = start_faces(rig.stations, rig.file)
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=3)
        assert client.connect()
        made.append((rig, faces, client))
        return rig, faces[0], client

    yield make
    for rig, faces, client in made:
        client.close()
        for f in faces:
            f.stop()
        rig.close()


def read(client, address: int, count: int) -> list[int]:
    r = client.read_holding_registers(address, count=count)
    assert not r.isError(), r
    return r.registers


def block(client, h: int) -> list[int]:
    return read(client, M.HOIST_BASE + h * M.HOIST_STRIDE, M.HOIST_STRIDE)


def test_the_map_header_and_a_hoists_values(served):
    rig, face, client = served(2)
    assert read(client, 0, 7) == [M.MAP_VERSION, 2, M.HOIST_BASE, M.HOIST_STRIDE, M.MAX_NODES, M.ROPES, 0]
    rig.step()
    rig.feed("h1", (5000, 5100, 4900, None), depth_mm=812_345, speed_mm_s=-9500, battery_mv=11_900,
             oil_temp_cc=2150)
    rig.step()
    b = block(client, 1)
    n = M.NODE_BASE
    assert b[M.NODES] == 1 and b[n + M.N_ID] == 1 and b[n + M.N_ROPES] == 4
    ropes = [s16(b[n + M.ROPE_BASE + 2 * r]) for r in range(4)]
    assert ropes == [5000, 5100, 4900, -32768]                # 0.01 kN; the absent rope is -32768
    devs = [s16(b[n + M.ROPE_BASE + 2 * r + 1]) for r in range(4)]
    assert devs == [0, 200, -200, -32768]                     # 0.01 %: +2 %, -2 % of the mean 5000
    assert s32(b[n + M.N_SUM], b[n + M.N_SUM + 1]) == -(1 << 31)   # a rope absent: no sum
    assert s32(b[n + M.N_DEPTH], b[n + M.N_DEPTH + 1]) == 812_345
    assert s16(b[n + M.N_SPEED]) == -9500 and b[n + M.N_BATTERY] == 11_900 and s16(b[n + M.N_OIL]) == 2150
    assert b[M.AGE] == 2 and b[n + M.N_AGE] == 2              # 0.25 s since the frame, in 0.1 s
    assert s32(b[n + M.N_SEQ], b[n + M.N_SEQ + 1]) == 1
    rig.feed("h1", (6000, 6000, 6000, 6000))
    rig.step()
    b = block(client, 1)
    assert s32(b[n + M.N_SUM], b[n + M.N_SUM + 1]) == 24_000 and b[M.FRAMES] == 2
    h0 = block(client, 0)
    assert h0[n + M.N_AGE] == M.AGE_NONE and h0[M.HB] == 0   # hoist 0 never heard: no heartbeat


def test_the_heartbeat_runs_while_the_station_vouches_and_stops_when_the_node_goes_silent(served):
    rig, face, client = served(1)
    silent_bit = 1 << ALARM_KINDS.index("silent")
    beats = []
    for _ in range(8):                          # 2 s at 4 ticks/s, a frame each tick
        rig.feed("h0")
        rig.step()
        beats.append(block(client, 0)[M.HB])
    assert beats == list(range(1, 9))
    assert block(client, 0)[M.STATUS] & M.ST_VOUCHED
    for _ in range(16):                         # 4 s without a frame: NODE SILENT after 2 s
        rig.step()
    b = block(client, 0)
    stopped = b[M.HB]
    assert 8 < stopped <= 8 + 9 and not b[M.STATUS] & M.ST_VOUCHED
    assert s32(b[M.PRESENT], b[M.PRESENT + 1]) & silent_bit
    assert s32(b[M.UNACKED], b[M.UNACKED + 1]) & silent_bit
    for _ in range(4):
        rig.step()
    assert block(client, 0)[M.HB] == stopped    # still stopped: a PLC trips on it
    for _ in range(6):                          # frames again: NODE SILENT clears after 1 s, it runs
        rig.feed("h0")
        rig.step()
    assert block(client, 0)[M.HB] > stopped


def test_read_only_unless_ack_coil(served):
    rig, face, client = served(1)
    r = client.write_coil(0, True)
    assert r.isError()
    r = client.write_register(M.HOIST_BASE, 7)
    assert r.isError()
    assert client.read_holding_registers(M.HOIST_BASE + M.HOIST_STRIDE, count=1).isError()   # past the map


def test_the_ack_coil_acknowledges_the_hoists_alarms_through_the_station(served):
    rig, face, client = served(2, "ack_coil = true\n")
    events = []
    rig.stations.hoists["h1"].pipeline.add(_Events(events))
    for _ in range(12):                         # 3 s: no frame, both hoists' nodes silent
        rig.step()
    silent_bit = 1 << ALARM_KINDS.index("silent")
    assert s32(*block(client, 1)[M.UNACKED:M.UNACKED + 2]) & silent_bit
    assert client.read_coils(0, count=2).bits[:2] == [True, True]
    assert not client.write_coil(1, True).isError()
    rig.step()                                  # the station carries it out at its next pump
    assert not s32(*block(client, 1)[M.UNACKED:M.UNACKED + 2])
    assert s32(*block(client, 1)[M.PRESENT:M.PRESENT + 2]) & silent_bit   # acknowledged, still present
    assert s32(*block(client, 0)[M.UNACKED:M.UNACKED + 2]) & silent_bit   # the other hoist untouched
    acks = [e for e in events if e.action == "ack"]
    assert acks and acks[0].operator.startswith("modbus 127.0.0.1:") and acks[0].operator.endswith("(modbus)")


def test_a_refused_coil_acknowledgement_is_logged_by_the_face_from_its_outcome(served, caplog, monkeypatch):
    """The station refuses the acknowledgement (here its engine refuses every one): the face
    logs its own command's refusal; another face's refused acknowledgement it does not log."""
    import logging
    from ropemon.station.pipeline import Acknowledge
    rig, face, client = served(1, "ack_coil = true\n")

    def refuse(*args, **kw):
        raise ValueError("acknowledging refused by the test")
    monkeypatch.setattr(rig.stations.hoists["h0"].alarms.engine, "ack", refuse)
    caplog.set_level(logging.WARNING, logger="ropemon.station.modbus")
    assert not client.write_coil(0, True).isError()          # answered at once
    rig.stations.submit("h0", Acknowledge("olga", "web"))
    rig.step()
    said = [r.getMessage() for r in caplog.records if r.name == "ropemon.station.modbus"]
    assert len(said) == 1 and "modbus 127.0.0.1:" in said[0] and "refused by the test" in said[0], said


def test_a_bad_modbus_table_is_refused_with_the_field(tmp_path):
    rig = Rig(tmp_path, 1, "[modbus]\nport = 70000\n")
    try:
        with pytest.raises(StationConfigError, match="modbus.port"):
            start_faces(rig.stations, rig.file)
    finally:
        rig.close()
    with pytest.raises(StationConfigError, match="modbus.colour"):
        M.parse_table({"colour": "red"})


class _Events:
    name = "events"

    def __init__(self, out):
        self.out = out

    def __getattr__(self, name):
        return lambda *a: None

    def on_event(self, e):
        self.out.append(e)


# -- map version 2: the pistons, the standing status, the equalizer's alarm bits -------------

#: Version 1's registers as docs/integration.md lists them, written out (not taken from the
#: module): hoist block offsets, node sub-block offsets (node sub-block 0 at 20)
V1_HOIST = (0, 1, 2, 3, 4, 5, 6, 7, 8)
V1_NODE = tuple(range(0, 22))


def _listener(rig, hoist):
    return next(x for x in rig.stations.hoists[hoist].pipeline.listeners if isinstance(x, M.ModbusValues))


def test_version_2_reads_the_positions_back_and_keeps_version_1s_registers(tmp_path):
    port = free_port()
    rig = Rig(tmp_path, 2, f"[modbus]\nport = {port}\n")     # stroke 0.1 m, margin 0.01 m (node.json)
    faces = start_faces(rig.stations, rig.file)
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=3)
    try:
        assert client.connect()
        assert read(client, 0, 7) == [2, 2, 100, 100, 2, 4, 0]       # map version 2, then as version 1
        rig.step()
        frame = dict(depth_mm=812_345, speed_mm_s=-9500, battery_mv=11_900, oil_temp_cc=2150)
        rig.feed("h0", (5000, 5100, 4900, None), version=2, **frame)             # a version 2 node
        rig.feed("h1", (5000, 5100, 4900, None), positions=(423, -455, 0, None),    # version 3
                 stroke_mask=0b0001_0010, **frame)
        rig.step()
        b0, b1 = block(client, 0), block(client, 1)
        n = 20
        # the version 3 node: position 0.1 mm signed, the stroke mask, the layout version
        assert [s16(b1[n + 22 + r]) for r in range(4)] == [423, -455, 0, -32768]
        assert b1[n + 26] == 0x12 and b1[n + 27] == 3
        assert [b1[n + 29 + r] for r in range(4)] == [1000] * 4 and b1[n + 33] == 100     # the stroke, the margin
        # the version 2 node: no positions, no stroke bits
        assert [s16(b0[n + 22 + r]) for r in range(4)] == [-32768] * 4 and b0[n + 26] == 0 and b0[n + 27] == 2
        # version 1's registers: the same values for the same tensions, with or without positions,
        # but for the alarm the stroke mask raises (below)
        assert [b0[a] for a in V1_HOIST if a not in (1, 2, 3, 4, 5)] == [b1[a] for a in V1_HOIST
                                                                         if a not in (1, 2, 3, 4, 5)]
        assert b0[1] == 0b01001 and b1[1] == 0b01111       # vouched, every node heard; h1: an alarm, unacknowledged
        assert [b0[n + a] for a in V1_NODE] == [b1[n + a] for a in V1_NODE]
        assert [s16(b1[n + 12 + 2 * r]) for r in range(4)] == [5000, 5100, 4900, -32768]
        assert [s16(b1[n + 13 + 2 * r]) for r in range(4)] == [0, 200, -200, -32768]
        assert s32(b1[n + 6], b1[n + 7]) == 812_345 and s16(b1[n + 8]) == -9500 and b1[n + 9] == 11_900
        assert s32(b1[n + 20], b1[n + 21]) == 1
        # the stroke limit the mask shows is an alarm: its own bit in the version 2 words, "any other
        # kind" (bit 16) in version 1's; none on the version 2 node
        assert s32(b1[2], b1[3]) == s32(b1[4], b1[5]) == 1 << 16
        assert s32(b1[9], b1[10]) == s32(b1[11], b1[12]) == 1 << EQUALIZER_KINDS.index("stroke_limit")
        assert s32(b0[2], b0[3]) == s32(b0[9], b0[10]) == 0
    finally:
        client.close()
        for f in faces:
            f.stop()
        rig.close()


def test_version_2_carries_the_equalizer_alarms_and_the_standing_status(served):
    from ropemon.station.alarms import ActiveAlarm
    from ropemon.station.pipeline import AlarmState
    rig, face, client = served(1)
    rig.feed("h0", positions=(10, 20, 30, 40))
    rig.step()
    v = _listener(rig, "h0")
    # the standing status: the alarm engine's hidden imbalance at this rope tension, 0.01 %
    st = rig.stations.hoists["h0"].alarms.engine.hoist_status(1)
    assert st is not None and 0 < st.hidden_frac < 1
    assert s16(block(client, 0)[M.NODE_BASE + M.N_HIDDEN]) == round(st.hidden_frac * 10000)
    # the equalizer's alarm kinds, each its bit (a hand-made alarm state, every kind at once)

    def alarm(kind, rope, present, latched):
        return ActiveAlarm(f"{kind}:n1:r{rope}", kind, 1, rope, present, latched, None, None, kind, 1.0)
    status = SimpleNamespace(hidden_frac=0.1634, text="the seals can hide 16.3 %")
    v.on_alarms(AlarmState(rig.now, (alarm("stroke_limit", 2, True, True), alarm("oil_loss", 0, False, True),
                                     alarm("deviation", 1, True, False)), {}, (), {1: status}))
    b = block(client, 0)
    assert s32(b[9], b[10]) == 1 << EQUALIZER_KINDS.index("stroke_limit")           # present
    assert s32(b[11], b[12]) == (1 << EQUALIZER_KINDS.index("stroke_limit")) | (1 << EQUALIZER_KINDS.index("oil_loss"))
    assert s32(b[2], b[3]) == (1 << 16) | (1 << ALARM_KINDS.index("deviation"))      # version 1: "any other kind"
    assert s32(b[4], b[5]) == (1 << 16)
    assert s16(b[M.NODE_BASE + 28]) == 1634                                          # 0.01 %
    v.on_alarms(AlarmState(rig.now, (), {}, (), {}))
    b = block(client, 0)
    assert s32(b[9], b[10]) == 0 and s32(b[11], b[12]) == 0 and s16(b[M.NODE_BASE + 28]) == -32768
