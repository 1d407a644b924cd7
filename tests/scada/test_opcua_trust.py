"""The OPC UA face's client trust list: with `trusted_clients` set, only client certificates in
that folder may open a session; a refused certificate lands in `rejected/`, and moving it into
the trusted folder lets that client in without a restart."""
from __future__ import annotations

import asyncio
import json
import shutil
import time

import pytest

asyncua = pytest.importorskip("asyncua")

from asyncua import Client, ua  # noqa: E402
from asyncua.crypto.cert_gen import setup_self_signed_certificate  # noqa: E402
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256  # noqa: E402
from cryptography import x509  # noqa: E402
from cryptography.hazmat.primitives import hashes  # noqa: E402
from cryptography.x509.oid import ExtendedKeyUsageOID  # noqa: E402

from ropemon.commission.nodejson import example_physical, make_node_json  # noqa: E402
from ropemon.lab.localnet import free_port  # noqa: E402
from ropemon.station.faces import start_faces  # noqa: E402
from ropemon.station.hoists import Station  # noqa: E402
from ropemon.station.opcua import parse_table  # noqa: E402
from ropemon.station.stationfile import load_station_file  # noqa: E402
from ropemon.station.users import add_user  # noqa: E402

KEY = bytes(range(16))


def _cert(d, name, uri):
    cert, key = d / f"{name}.der", d / f"{name}-key.pem"
    asyncio.run(setup_self_signed_certificate(key, cert, uri, "localhost", [ExtendedKeyUsageOID.CLIENT_AUTH],
                                              {"commonName": name}))
    return cert, key, uri


@pytest.fixture(scope="module")
def certs(tmp_path_factory):
    d = tmp_path_factory.mktemp("clients")
    return {"scada": _cert(d, "scada client", "urn:ropemon:test:scada"),
            "stranger": _cert(d, "stranger client", "urn:ropemon:test:stranger")}


@pytest.fixture(scope="module")
def rig(tmp_path_factory, certs):
    d = tmp_path_factory.mktemp("station")
    (d / "north.json").write_text(json.dumps(make_node_json(example_physical(), node_id=1, key=KEY)))
    add_user(d / "users.toml", "alice", "operator", "rope-pw-1")
    port = free_port()
    (d / "station.toml").write_text(f"""
[station]
name = "trust test"

[[hoist]]
id = "north"
configs = ["north.json"]
receivers = {{ pithead = "loop://" }}

[opcua]
endpoint = "opc.tcp://127.0.0.1:{port}/ropemon"
certificates = "pki"
users = "users.toml"
trusted_clients = "pki/trusted"
""")
    (d / "pki" / "trusted").mkdir(parents=True)
    shutil.copy(certs["scada"][0], d / "pki" / "trusted" / "scada.der")
    sf = load_station_file(d / "station.toml")
    stations = Station(sf, clock=time.time)
    faces = start_faces(stations, sf)
    yield {"dir": d, "url": f"opc.tcp://127.0.0.1:{port}/ropemon", "face": faces[0]}
    for f in faces:
        f.stop()
    stations.close()


async def _connect(rig, cert, key, uri, forge=None) -> Client:
    c = Client(rig["url"], timeout=10)
    c.application_uri = uri
    c.set_user("alice")
    c.set_password("rope-pw-1")
    await c.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key),
                         server_certificate=str(rig["dir"] / "pki" / "server.der"),
                         mode=ua.MessageSecurityMode.SignAndEncrypt)
    if forge is not None:      # CreateSession names another's certificate than the secure channel's
        create = c.uaclient.create_session

        async def forged(params):
            params.ClientCertificate = forge
            return await create(params)
        c.uaclient.create_session = forged
    await c.connect()
    return c


async def _reads(c: Client) -> bool:
    return await c.get_namespace_index("urn:ropemon:opcua") >= 1


def test_the_table_takes_a_trusted_folder_beside_which_rejected_certificates_go(tmp_path):
    cfg = parse_table({"users": "u.toml", "trusted_clients": "pki/trusted"}, tmp_path)
    assert cfg.trusted_clients == tmp_path / "pki" / "trusted"
    assert cfg.rejected_clients == tmp_path / "pki" / "rejected"
    assert parse_table({"users": "u.toml"}, tmp_path).trusted_clients is None


def test_a_trusted_client_connects(rig, certs):
    async def go():
        c = await _connect(rig, *certs["scada"])
        try:
            assert await _reads(c)
        finally:
            await c.disconnect()
    asyncio.run(go())
    assert "pki/trusted only" in rig["face"].describe()


def test_an_untrusted_client_is_refused_and_its_certificate_kept_in_rejected(rig, certs):
    cert, key, uri = certs["stranger"]

    async def go():
        with pytest.raises(ua.UaStatusCodeError, match="BadCertificateUntrusted"):
            await _connect(rig, cert, key, uri)
    asyncio.run(go())
    der = cert.read_bytes()
    thumb = x509.load_der_x509_certificate(der).fingerprint(hashes.SHA1()).hex().upper()
    (kept,) = [f for f in (rig["dir"] / "pki" / "rejected").iterdir() if f.name.endswith(f" [{thumb}].der")]
    assert kept.name.startswith("urn_ropemon_test_stranger")       # its common name, made safe for a file name
    assert kept.read_bytes() == der
    assert not (rig["dir"] / "pki" / "trusted" / kept.name).exists()


def test_a_certificate_named_in_create_session_but_not_the_channels_is_refused(rig, certs):
    """The secure channel opened with the stranger's certificate, CreateSession naming the trusted
    one (public, anyone may have it): the session is refused at activation."""
    cert, key, uri = certs["stranger"]

    async def go():
        with pytest.raises(ua.UaStatusCodeError, match="BadCertificateUntrusted"):
            c = await _connect(rig, cert, key, uri, forge=certs["scada"][0].read_bytes())
            await c.disconnect()
    asyncio.run(go())


def test_moving_a_rejected_certificate_into_trusted_lets_it_in_without_a_restart(rig, certs):
    cert, key, uri = certs["stranger"]
    rejected = rig["dir"] / "pki" / "rejected"

    async def refused():
        with pytest.raises(ua.UaStatusCodeError, match="BadCertificateUntrusted"):
            await _connect(rig, cert, key, uri)
    asyncio.run(refused())
    (kept,) = [f for f in rejected.iterdir() if f.read_bytes() == cert.read_bytes()]
    kept.rename(rig["dir"] / "pki" / "trusted" / kept.name)

    async def go():
        c = await _connect(rig, cert, key, uri)
        try:
            assert await _reads(c)
        finally:
            await c.disconnect()
    asyncio.run(go())
