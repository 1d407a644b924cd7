"""The OPC UA face: a station file with [opcua], frames fed to the hoist's station, an asyncua
client over Basic256Sha256 Sign&Encrypt with a user: values, EURange, alarm conditions,
Acknowledge into the log with the user, anonymous refused, history from the log."""
from __future__ import annotations

import asyncio
import json
import stat
import time
from pathlib import Path

import pytest

asyncua = pytest.importorskip("asyncua")

from asyncua import Client, ua  # noqa: E402
from asyncua.crypto.cert_gen import setup_self_signed_certificate  # noqa: E402
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256  # noqa: E402
from cryptography.x509.oid import ExtendedKeyUsageOID  # noqa: E402

from ropemon.lab.localnet import free_port
from ropemon.commission.nodejson import example_physical, make_node_json  # noqa: E402
from ropemon.station.faces import start_faces  # noqa: E402
from ropemon.station.hoists import Station  # noqa: E402
from ropemon.station.opcua import parse_table  # noqa: E402
from ropemon.station.protocol import encode_frame  # noqa: E402
from ropemon.station.stationfile import StationConfigError, load_station_file  # noqa: E402
from ropemon.station.store import Store  # noqa: E402
from ropemon.station.users import add_user  # noqa: E402

KEY = bytes(range(16))
CLIENT_URI = "urn:ropemon:test-client"


@pytest.fixture(scope="module")
def client_cert(tmp_path_factory):
    d = tmp_path_factory.mktemp("client")
    cert, key = d / "client.der", d / "client-key.pem"
    asyncio.run(setup_self_signed_certificate(key, cert, CLIENT_URI, "localhost",
                                              [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "test client"}))
    return cert, key


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """A station of one hoist with [opcua] on a free port; its clock runs on the test's frames."""
    d = tmp_path_factory.mktemp("station")
    (d / "north.json").write_text(json.dumps(make_node_json(example_physical(), node_id=1, key=KEY)))
    add_user(d / "users.toml", "alice", "operator", "rope-pw-1")      # the web face's users file, 0600
    add_user(d / "users.toml", "victor", "viewer", "view-pw-2")
    port = free_port()
    (d / "station.toml").write_text(f"""
[station]
name = "test shaft"
data_dir = "data"

[[hoist]]
id = "north"
name = "North shaft"
configs = ["north.json"]
receivers = {{ pithead = "loop://" }}

[opcua]
endpoint = "opc.tcp://127.0.0.1:{port}/ropemon"
certificates = "pki"
users = "users.toml"
""")
    sf = load_station_file(d / "station.toml")
    clock = [time.time()]
    stations = Station(sf, clock=lambda: clock[0])
    faces = start_faces(stations, sf)
    rig = {"dir": d, "url": f"opc.tcp://127.0.0.1:{port}/ropemon", "stations": stations, "clock": clock,
           "seq": [100], "face": faces[0]}
    yield rig
    for f in faces:
        f.stop()
    stations.close()


def feed(rig, tensions_dan, n=1, dt=0.1, positions=None, **kw):
    """`n` frames of node 1 with these rope tensions (and piston positions, 0.1 mm, None: absent;
    `version`, `stroke_mask` in kw), the station clock `dt` apart; then a tick."""
    st = rig["stations"].hoists["north"].pipeline
    for _ in range(n):
        rig["seq"][0] += 1
        rig["clock"][0] += dt
        ropes = [(t, t - 5, t + 5, 2000) for t in tensions_dan]
        if positions is not None:
            ropes = [r + (-32768 if x is None else x,) for r, x in zip(ropes, positions)]
        st.feed("pithead", encode_frame(node=1, seq=rig["seq"][0], key=KEY, ropes=ropes, depth_mm=123_456,
                                        speed_mm_s=2500, battery_mv=12_300, oil_temp_cc=2150, **kw)[1])
    rig["stations"].step()


def client(rig, client_cert, user="alice", password="rope-pw-1", secure=True) -> Client:
    c = Client(rig["url"], timeout=10)
    c.application_uri = CLIENT_URI
    if secure:
        cert, key = client_cert
        c._pending_security = (cert, key, rig["dir"] / "pki" / "server.der")
    if user is not None:
        c.set_user(user)
        c.set_password(password)
    return c


async def connect(rig, client_cert, **kw) -> Client:
    c = client(rig, client_cert, **kw)
    if getattr(c, "_pending_security", None):
        cert, key, server_cert = c._pending_security
        await c.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key), server_certificate=str(server_cert),
                             mode=ua.MessageSecurityMode.SignAndEncrypt)
    await c.connect()
    return c


async def pumped(rig, call):
    """A method call that reaches the station, awaited while the station's thread (the test's)
    pumps: the face answers with its command's outcome once the station has carried it out."""
    task = asyncio.ensure_future(call)
    while not task.done():
        rig["stations"].hoists["north"].pipeline.pump()
        await asyncio.sleep(0.01)
    return task.result()


async def until(pred, timeout=10.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        v = await pred()
        if v:
            return v
        await asyncio.sleep(0.05)
    raise AssertionError("timed out")


def test_certificate_made_on_first_start_with_an_owner_only_key(rig):
    pki = rig["dir"] / "pki"
    assert (pki / "server.der").stat().st_size > 500
    assert stat.S_IMODE((pki / "server-key.pem").stat().st_mode) == 0o600
    assert "opc.tcp://127.0.0.1" in rig["face"].describe()


def test_tensions_units_eurange_and_updates(rig, client_cert):
    async def go():
        c = await connect(rig, client_cert)
        try:
            idx = await c.get_namespace_index("urn:ropemon:opcua")
            feed(rig, [5000, 5100, 4900, 5000])
            t1 = c.get_node(ua.NodeId("north.n1.r1.Tension", idx))
            await until(lambda: _value_is(t1, 50.0))
            rope2 = await c.nodes.objects.get_child([f"{idx}:Ropemon", f"{idx}:north", f"{idx}:Node1",
                                                     f"{idx}:Rope2", f"{idx}:Tension"])
            assert await rope2.read_value() == pytest.approx(51.0)
            rng = await (await rope2.get_child("0:EURange")).read_value()
            assert rng.Low == 0.0 and rng.High == pytest.approx(26562500.0 * 0.007853981633974483 / 1000, abs=0.1)
            eu = await (await rope2.get_child("0:EngineeringUnits")).read_value()
            assert eu.DisplayName.Text == "kN" and eu.UnitId == 0x423437  # UNECE B47
            dv = await t1.read_data_value()
            assert abs(dv.SourceTimestamp.timestamp() - time.time()) < 10      # the frame's receipt, wall time
            depth = c.get_node(ua.NodeId("north.n1.Depth", idx))
            assert await depth.read_value() == pytest.approx(123.456)
            assert await c.get_node(ua.NodeId("north.n1.Sum", idx)).read_value() == pytest.approx(200.0)
            assert await c.get_node(ua.NodeId("north.n1.r2.Deviation", idx)).read_value() == pytest.approx(2.0)
            assert await c.get_node(ua.NodeId("north.n1.OilTemperature", idx)).read_value() == pytest.approx(21.5)
            assert await c.get_node(ua.NodeId("north.n1.Battery", idx)).read_value() == pytest.approx(12.3)
            # a subscription sees the next value
            seen: list[float] = []

            class Handler:
                def datachange_notification(self, node, val, data):
                    seen.append(val)
            sub = await c.create_subscription(50, Handler())
            await sub.subscribe_data_change(t1)
            feed(rig, [6000, 6000, 6000, 6000])

            async def got():
                return 60.0 in seen
            await until(got)
            await sub.delete()
        finally:
            await c.disconnect()
    asyncio.run(go())


async def _value_is(node, v):
    try:
        return await node.read_value() == pytest.approx(v)
    except ua.UaStatusCodeError:
        return False


def test_deviation_alarm_condition_and_acknowledge_lands_in_the_log_with_the_user(rig, client_cert):
    async def go():
        c = await connect(rig, client_cert)
        try:
            events = []

            class Handler:
                def event_notification(self, event):
                    events.append(event)
            sub = await c.create_subscription(50, Handler())
            await sub.subscribe_alarms_and_conditions(c.nodes.server, ua.ObjectIds.AlarmConditionType)
            feed(rig, [5000, 5000, 5000, 5000], n=3)
            feed(rig, [5000, 6500, 5000, 5000], n=10)         # rope 2 ~ +22 %: DEVIATION after 0.5 s

            async def raised():
                return [e for e in events if e.ConditionName == "deviation:n1:r1"
                        and getattr(e, "ActiveState/Id") and not getattr(e, "AckedState/Id")]
            (ev,) = (await until(raised))[:1]
            assert ev.Severity == 800 and ev.Retain is True and "rope 2" in ev.Message.Text
            cond = c.get_node(ev.NodeId)
            # a viewer may not acknowledge
            v = await connect(rig, client_cert, user="victor", password="view-pw-2")
            try:
                with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
                    await v.get_node(ev.NodeId).call_method(
                        ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge),
                        ua.Variant(ev.EventId, ua.VariantType.ByteString), ua.LocalizedText("no"))
            finally:
                await v.disconnect()
            await pumped(rig, cond.call_method(ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge),
                                               ua.Variant(ev.EventId, ua.VariantType.ByteString),
                                               ua.LocalizedText("seen")))
            feed(rig, [5000, 6500, 5000, 5000])               # carried out at the station's pump: the next event

            async def acked():
                return [e for e in events if e.ConditionName == "deviation:n1:r1" and getattr(e, "AckedState/Id")
                        and getattr(e, "ActiveState/Id")]
            (ack,) = (await until(acked))[:1]
            assert ack.ClientUserId == "alice (opcua)"
            await sub.delete()
        finally:
            await c.disconnect()
    asyncio.run(go())
    h = rig["stations"].hoists["north"]
    h.store.commit()
    with Store(h.db_path, readonly=True) as s:
        acks = [e for e in s.events() if e["action"] == "ack" and e["alarm"] == "deviation:n1:r1"]
    assert acks and acks[0]["operator"] == "alice (opcua)"


def test_anonymous_and_wrong_password_refused(rig, client_cert):
    async def go():
        with pytest.raises(ua.UaStatusCodeError):
            await connect(rig, client_cert, user=None)
        with pytest.raises(ua.UaStatusCodeError):
            await connect(rig, client_cert, password="wrong")
        c = Client(rig["url"], timeout=5)          # no encryption: no such endpoint
        with pytest.raises(Exception):
            await c.connect()
    asyncio.run(go())


def test_allow_anonymous_admits_a_client_without_a_name_over_the_secure_channel(client_cert):
    """Every endpoint signs and encrypts, so an anonymous session always comes with the channel's
    certificate: allow_anonymous admits it (with no name: a viewer), and without it it is refused."""
    from ropemon.station.opcua.certs import _UserManager
    cert = client_cert[0].read_bytes()
    user = _UserManager(None, allow_anonymous=True).get_user(None, certificate=cert)
    assert user is not None and user.name is None
    assert _UserManager(None, allow_anonymous=False).get_user(None, certificate=cert) is None
    assert _UserManager(None, allow_anonymous=True).get_user(None, "alice", "pw", certificate=cert) is None


def test_history_read_returns_the_stored_tensions(rig, client_cert):
    t0 = time.time()
    for t in (7000, 7100, 7200):
        feed(rig, [t, t, t, t])
    h = rig["stations"].hoists["north"]
    h.store.commit()

    async def go():
        c = await connect(rig, client_cert)
        try:
            idx = await c.get_namespace_index("urn:ropemon:opcua")
            node = c.get_node(ua.NodeId("north.n1.r3.Tension", idx))
            assert (await node.read_attribute(ua.AttributeIds.Historizing)).Value.Value is True
            got = await node.read_raw_history(_utc(t0 - 1), _utc(time.time() + 1))
            assert [dv.Value.Value for dv in got][-3:] == [70.0, 71.0, 72.0]
            assert all(dv.SourceTimestamp.timestamp() >= t0 - 1 for dv in got)
            raw = c.get_node(ua.NodeId("north.n1.r3.RawTension", idx))
            got = await raw.read_raw_history(_utc(t0 - 1), _utc(time.time() + 1))
            assert got and got[-1].Value.Value == pytest.approx(2000 * 0.007853981633974483)
        finally:
            await c.disconnect()
    asyncio.run(go())


def _utc(t):
    import datetime
    return datetime.datetime.fromtimestamp(t, datetime.timezone.utc)


@pytest.mark.parametrize("table, field", [
    ({"endpoint": "http://x:1/"}, "opcua.endpoint"),
    ({"users": "u.toml", "security": ["None"]}, "opcua.security[0]"),
    ({"users": "u.toml", "port": 4840}, "opcua.port"),
    ({"allow_anonymous": "yes"}, "opcua.allow_anonymous"),
    ({}, "opcua.users"),
])
def test_the_table_is_refused_with_the_field_named(table, field):
    with pytest.raises(StationConfigError, match=field.replace("[", r"\[").replace("]", r"\]")):
        parse_table(table, Path("."))


SHELVE = ua.NodeId(ua.ObjectIds.ShelvedStateMachineType_TimedShelve)
SHELVE2 = ua.NodeId(ua.ObjectIds.ShelvedStateMachineType_TimedShelve2)
ONE_SHOT = ua.NodeId(ua.ObjectIds.ShelvedStateMachineType_OneShotShelve)
UNSHELVE = ua.NodeId(ua.ObjectIds.ShelvedStateMachineType_Unshelve)


def _log_events(rig, action, alarm):
    h = rig["stations"].hoists["north"]
    h.store.commit()
    with Store(h.db_path, readonly=True) as s:
        return [e for e in s.events() if e["action"] == action and e["alarm"] == alarm]


def test_shelving_methods_become_the_stations_shelve_and_unshelve_with_the_user(rig, client_cert):
    aid = "deviation:n1:r1"

    async def go():
        c = await connect(rig, client_cert)
        try:
            events = []

            class Handler:
                def event_notification(self, event):
                    events.append(event)
            sub = await c.create_subscription(50, Handler())
            await sub.subscribe_alarms_and_conditions(c.nodes.server, ua.ObjectIds.AlarmConditionType)
            feed(rig, [5000, 6500, 5000, 5000], n=10)      # the deviation present (raised by the test above or now)
            await c.get_node(ua.NodeId(ua.ObjectIds.ConditionType)).call_method(   # its state now
                ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
                ua.Variant(sub.subscription_id, ua.VariantType.UInt32))

            async def present():
                return [e for e in events if e.ConditionName == aid and getattr(e, "ActiveState/Id")]
            ev = (await until(present))[-1]
            shelving = await c.get_node(ev.NodeId).get_child("2:ShelvingState")
            # the ShelvedStateMachineType's methods are there to browse
            names = {(await m.read_browse_name()).Name for m in await shelving.get_methods()}
            assert {"TimedShelve", "OneShotShelve", "Unshelve"} <= names
            v = await connect(rig, client_cert, user="victor", password="view-pw-2")
            try:
                with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
                    await v.get_node(shelving.nodeid).call_method(SHELVE, ua.Variant(60_000.0, ua.VariantType.Double))
            finally:
                await v.disconnect()
            with pytest.raises(ua.UaStatusCodeError, match="BadShelvingTimeOutOfRange"):
                await shelving.call_method(SHELVE, ua.Variant(0.0, ua.VariantType.Double))
            with pytest.raises(ua.UaStatusCodeError, match="BadConditionNotShelved"):
                await shelving.call_method(UNSHELVE)
            await pumped(rig, shelving.call_method(SHELVE2, ua.Variant(600_000.0, ua.VariantType.Double),
                                                   ua.LocalizedText("rope 2 being re-tensioned")))
            feed(rig, [5000, 6500, 5000, 5000])

            async def shelved():
                return [e for e in events if e.ConditionName == aid
                        and getattr(e, "ShelvingState/CurrentState").Text == "TimedShelved"]
            sh = (await until(shelved))[-1]
            assert sh.SuppressedOrShelved is True and getattr(sh, "SuppressedState/Id") is False
            assert getattr(sh, "ShelvingState/CurrentState/Id") == ua.NodeId(2932)
            assert 0 < getattr(sh, "ShelvingState/UnshelveTime") <= 600_000.0
            with pytest.raises(ua.UaStatusCodeError, match="BadConditionAlreadyShelved"):
                await shelving.call_method(SHELVE, ua.Variant(60_000.0, ua.VariantType.Double))
            await pumped(rig, shelving.call_method(UNSHELVE))
            feed(rig, [5000, 6500, 5000, 5000])

            async def unshelved():
                return [e for e in events[events.index(sh):] if e.ConditionName == aid
                        and getattr(e, "ShelvingState/CurrentState").Text == "Unshelved"]
            await until(unshelved)
            # OneShotShelve: shelved until the alarm returns to normal, then unshelved by the face
            await pumped(rig, shelving.call_method(ONE_SHOT))
            feed(rig, [5000, 6500, 5000, 5000])

            async def one_shot():
                return [e for e in events if e.ConditionName == aid
                        and getattr(e, "ShelvingState/CurrentState").Text == "OneShotShelved"]
            await until(one_shot)

            async def back_to_normal():
                feed(rig, [5000, 5000, 5000, 5000], n=5)
                return [e for e in _log_events(rig, "unshelve", aid) if e["operator"] == "alice (opcua one-shot)"]
            await until(back_to_normal, timeout=20)
            await sub.delete()
        finally:
            await c.disconnect()
    asyncio.run(go())
    shelves = _log_events(rig, "shelve", aid)
    assert [e["operator"] for e in shelves][-2:] == ["alice (opcua)", "alice (opcua)"]
    assert "rope 2 being re-tensioned" in shelves[-2]["message"]
    assert "OneShotShelve" in shelves[-1]["message"]
    assert [e["operator"] for e in _log_events(rig, "unshelve", aid)] == ["alice (opcua)", "alice (opcua one-shot)"]


def test_a_refused_command_is_its_callers_method_result_and_no_other_faces(rig, client_cert, caplog, monkeypatch):
    """The station refuses a shelve (here its engine refuses every one): the OPC UA caller's
    TimedShelve fails with BadInvalidState and the face logs its own refusal; another face's
    refused command (the web's) is not taken for the OPC UA face's: the face logs nothing of it."""
    import logging
    from ropemon.station.pipeline import Shelve
    aid = "deviation:n1:r1"
    h = rig["stations"].hoists["north"]

    def refuse(*args, **kw):
        raise ValueError("shelving refused by the test")
    monkeypatch.setattr(h.alarms.engine, "shelve", refuse)
    caplog.set_level(logging.WARNING, logger="ropemon.station.opcua")

    async def go():
        c = await connect(rig, client_cert)
        try:
            events = []

            class Handler:
                def event_notification(self, event):
                    events.append(event)
            sub = await c.create_subscription(50, Handler())
            await sub.subscribe_alarms_and_conditions(c.nodes.server, ua.ObjectIds.AlarmConditionType)
            feed(rig, [5000, 6500, 5000, 5000], n=10)
            await c.get_node(ua.NodeId(ua.ObjectIds.ConditionType)).call_method(
                ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
                ua.Variant(sub.subscription_id, ua.VariantType.UInt32))

            async def present():
                return [e for e in events if e.ConditionName == aid and getattr(e, "ActiveState/Id")]
            ev = (await until(present))[-1]
            shelving = await c.get_node(ev.NodeId).get_child("2:ShelvingState")
            with pytest.raises(ua.UaStatusCodeError, match="BadInvalidState"):
                await pumped(rig, shelving.call_method(SHELVE, ua.Variant(60_000.0, ua.VariantType.Double)))
            web = rig["stations"].submit("north", Shelve("olga", "web", alarm=aid, minutes=5, reason="rope change"))
            await pumped(rig, asyncio.wrap_future(web))
            out = web.result()
            assert not out.ok and out.reason == "shelving refused by the test" and out.command.via == "web"
            await sub.delete()
        finally:
            await c.disconnect()
    asyncio.run(go())
    said = [r.getMessage() for r in caplog.records if r.name == "ropemon.station.opcua"]
    assert len(said) == 1 and "alice" in said[0] and "shelving refused by the test" in said[0], said
    refused = [e["operator"] for e in _log_events(rig, "refused", aid)]
    assert refused[-2:] == ["alice (opcua)", "olga (web)"]


def test_event_history_reads_the_logs_alarm_events(rig, client_cert):
    from ropemon.station.pipeline import Shelve, Unshelve
    t0 = time.time() - 3600
    feed(rig, [5000, 6500, 5000, 5000], n=10)         # the deviation raised (if not yet), then an operator's actions
    rig["stations"].submit("north", Shelve("carol", "terminal", alarm="deviation:n1:r1", minutes=5, reason="test"))
    feed(rig, [5000, 6500, 5000, 5000])
    rig["stations"].submit("north", Unshelve("carol", "terminal", alarm="deviation:n1:r1"))
    feed(rig, [5000, 5000, 5000, 5000])
    rig["stations"].hoists["north"].store.commit()

    async def go():
        c = await connect(rig, client_cert)
        try:
            idx = await c.get_namespace_index("urn:ropemon:opcua")
            evtype = c.get_node(ua.NodeId(ua.ObjectIds.AlarmConditionType))
            got = await c.nodes.server.read_event_history(_utc(t0), _utc(rig["clock"][0] + 1), evtypes=[evtype])
            hoist = c.get_node(ua.NodeId("north", idx))
            own = await hoist.read_event_history(_utc(t0), _utc(rig["clock"][0] + 1), evtypes=[evtype])
            newest = await c.nodes.server.read_event_history(None, _utc(rig["clock"][0] + 1), numvalues=2,
                                                              evtypes=[evtype])
            return got, own, newest, idx
        finally:
            await c.disconnect()
    got, own, newest, idx = asyncio.run(go())
    h = rig["stations"].hoists["north"]
    with Store(h.db_path, readonly=True) as s:
        logged = s.events()
    assert len(got) == len(logged) == len(own) and len(logged) >= 4
    raised = [e for e in got if e.ConditionName == "deviation:n1:r1" and e.Message.Text.startswith("raise:")]
    assert raised and getattr(raised[0], "ActiveState/Id") is True and raised[0].Severity == 800
    assert raised[0].SourceNode == ua.NodeId("north.n1.r2", idx)
    # every row, in order, with its action and who acted
    assert [(e.Message.Text.split(":")[0], e.ClientUserId) for e in got] == \
        [(r["action"], r["operator"] or "") for r in logged]
    assert ("shelve", "carol (terminal)") in [(e.Message.Text.split(":")[0], e.ClientUserId) for e in got]
    assert all(getattr(e, "AckedState/Id") is True for e in got if e.Message.Text.startswith("ack:"))
    times = [e.Time for e in got]
    assert times == sorted(times)
    assert [e.Time for e in newest] == sorted(times, reverse=True)[:2]


def test_piston_positions_in_mm_with_the_stroke_as_eurange_and_the_stroke_limit_state(rig, client_cert):
    strokes = rig["stations"].hoists["north"].figures.stroke_m

    async def go():
        c = await connect(rig, client_cert)
        try:
            idx = await c.get_namespace_index("urn:ropemon:opcua")
            node = {k: c.get_node(ua.NodeId(f"north.n1.r{k}.Position", idx)) for k in range(1, 5)}
            feed(rig, [5000, 5100, 4900, 5000], positions=(423, -455, 0, None), stroke_mask=0b0001_0010)
            await until(lambda: _value_is(node[1], 42.3))
            assert await node[2].read_value() == pytest.approx(-45.5)
            assert await node[3].read_value() == 0.0
            with pytest.raises(ua.UaStatusCodeError, match="BadSensorFailure"):     # no healthy sample
                await node[4].read_value()
            rope2 = await c.nodes.objects.get_child([f"{idx}:Ropemon", f"{idx}:north", f"{idx}:Node1",
                                                     f"{idx}:Rope2", f"{idx}:Position"])
            eu = await (await rope2.get_child("0:EngineeringUnits")).read_value()
            assert eu.DisplayName.Text == "mm" and eu.UnitId == 0x4D4D54                    # UNECE MMT
            assert strokes == [0.1] * 4                                  # node.json's stroke_m
            for k in (1, 4):
                rng = await (await node[k].get_child("0:EURange")).read_value()     # the end stops
                assert (rng.Low, rng.High) == pytest.approx((-50.0, 50.0))
            near = {(k, end): await c.get_node(ua.NodeId(f"north.n1.r{k}.Near{end}End", idx)).read_value()
                    for k in range(1, 5) for end in ("Retracted", "Extended")}
            assert {key for key, v in near.items() if v} == {(1, "Extended"), (2, "Retracted")}
            feed(rig, [5000, 5100, 4900, 5000], positions=(-20, 0, 0, 0))
            await until(lambda: _value_is(node[1], -2.0))
            assert not await c.get_node(ua.NodeId("north.n1.r1.NearExtendedEnd", idx)).read_value()
            feed(rig, [5000, 5100, 4900, 5000], version=2)                # a version 2 node: no position

            async def no_data():
                try:
                    await node[1].read_value()
                except ua.UaStatusCodeError as e:
                    return "BadNoData" in str(e)
                return False
            await until(no_data)
        finally:
            await c.disconnect()
    asyncio.run(go())


def test_the_nodes_standing_status_hidden_imbalance_and_its_text(rig, client_cert):
    from types import SimpleNamespace
    engine = rig["stations"].hoists["north"].alarms.engine
    real = getattr(engine, "hoist_status", None)
    feed(rig, [5000, 5000, 5000, 5000])
    expect = real(1) if real is not None else None
    if expect is None:      # the alarm engine gives none here (no band): one of the test's
        expect = SimpleNamespace(hidden_frac=0.1634, text="the seals can hide 16.3 % of a rope's tension")
        engine.hoist_status = lambda node: expect if node == 1 else None

    async def go():
        c = await connect(rig, client_cert)
        try:
            idx = await c.get_namespace_index("urn:ropemon:opcua")
            hidden = c.get_node(ua.NodeId("north.n1.HiddenImbalance", idx))
            feed(rig, [5000, 5000, 5000, 5000])
            await until(lambda: _value_is(hidden, round(rig_status().hidden_frac * 100, 3)))
            text = await c.get_node(ua.NodeId("north.n1.StandingStatus", idx)).read_value()
            assert text == rig_status().text and text
            eu = await (await hidden.get_child("0:EngineeringUnits")).read_value()
            assert eu.DisplayName.Text == "%"
        finally:
            await c.disconnect()

    def rig_status():
        return engine.hoist_status(1)
    try:
        asyncio.run(go())
    finally:
        if real is None:
            del engine.hoist_status


def test_a_stroke_limit_is_an_alarm_condition_on_its_rope(rig, client_cert):
    """A piston within the stroke margin (the frame's stroke mask) raises the station's
    stroke_limit alarm: an AlarmConditionType event whose source is that rope's object."""
    async def go():
        c = await connect(rig, client_cert)
        try:
            idx = await c.get_namespace_index("urn:ropemon:opcua")
            events = []

            class Handler:
                def event_notification(self, event):
                    events.append(event)
            sub = await c.create_subscription(50, Handler())
            await sub.subscribe_alarms_and_conditions(c.nodes.server, ua.ObjectIds.AlarmConditionType)
            feed(rig, [5000, 5000, 5000, 5000], positions=(0, 0, 0, 0), n=3)
            feed(rig, [5000, 5000, 5000, 5000], positions=(0, 0, 450, 0), stroke_mask=1 << (4 + 2), n=3)

            async def raised():
                return [e for e in events if e.ConditionName == "stroke_limit:n1:r2" and getattr(e, "ActiveState/Id")]
            (ev,) = (await until(raised))[:1]
            assert ev.SourceNode == ua.NodeId("north.n1.r3", idx)
            assert ev.Severity == 800 and ev.Retain is True and "rope 3" in ev.Message.Text
            assert await c.get_node(ua.NodeId("north.n1.r3.NearExtendedEnd", idx)).read_value() is True
            await sub.delete()
        finally:
            await c.disconnect()
    asyncio.run(go())
