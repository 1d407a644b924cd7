"""The MQTT face and the fleet consumer over TLS with a username and password, against a
Mosquitto with a password file and a TLS listener whose CA and server certificate are made
here; a wrong password is refused and said clearly, without a station fault."""
from __future__ import annotations

import datetime
import ipaddress
import logging
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("paho.mqtt")

import paho.mqtt.client as paho  # noqa: E402
from cryptography import x509  # noqa: E402
from cryptography.hazmat.primitives import hashes, serialization  # noqa: E402
from cryptography.hazmat.primitives.asymmetric import ec  # noqa: E402
from cryptography.x509.oid import NameOID  # noqa: E402

from ropemon.lab.localnet import Broker, available  # noqa: E402
from ropemon.station.faces import start_faces  # noqa: E402
from ropemon.station.mqtt.fleet import Fleet, Historian  # noqa: E402
from scada_rig import Rig, wait  # noqa: E402

USERS = {"ropemon": "rope-s3cret", "fleet": "fleet-s3cret"}


def _pem_key(key) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def make_pki(d: Path) -> tuple[Path, Path, Path]:
    """A CA and a server certificate for 127.0.0.1 and localhost signed by it: (ca, cert, key)."""
    now = datetime.datetime.now(datetime.timezone.utc)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "ropemon test CA")])
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
          .not_valid_after(now + datetime.timedelta(days=1))
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                       content_commitment=False, key_encipherment=False, data_encipherment=False,
                                       key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
          .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False)
          .sign(ca_key, hashes.SHA256()))
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "localhost")]))
            .issuer_name(ca_name).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                                        x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                           critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([x509.oid.ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    paths = d / "ca.pem", d / "server.pem", d / "server.key"
    paths[0].write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    paths[1].write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    paths[2].write_bytes(_pem_key(key))
    return paths


@pytest.fixture
def tls_broker(tmp_path):
    if not available():
        pytest.fail("mosquitto is missing: `make test` installs it (apt-get install mosquitto, as root)")
    pki = tmp_path / "pki"
    pki.mkdir()
    b = Broker(tmp_path, users=USERS, tls=make_pki(pki))
    yield b
    b.close()


def station(d: Path, port: int, edge: str, password: str, tls_ca: bool = True, n: int = 1) -> Rig:
    d.mkdir()
    (d / "mqtt-password").write_text(password + "\n")
    if tls_ca:
        (d / "ca.pem").write_bytes((d.parent / "pki" / "ca.pem").read_bytes())
    extra = ('username = "ropemon"\npassword_file = "mqtt-password"\ntls = true\n'
             + ('tls_ca = "ca.pem"\n' if tls_ca else ""))
    return Rig(d, n, f'[mqtt]\nport = {port}\ngroup_id = "mine"\nedge_node_id = "{edge}"\n{extra}')


def test_the_station_publishes_and_the_fleet_reads_over_tls_with_a_password(tmp_path, tls_broker):
    port = tls_broker.port
    # the broker's own checks first: anonymous and plain-text clients are refused
    anon = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="anon")
    anon.tls_set(ca_certs=str(tmp_path / "pki" / "ca.pem"))
    refused = threading.Event()
    anon.on_connect = lambda c, u, f, reason, p: reason.is_failure and refused.set()
    anon.connect("127.0.0.1", port)
    anon.loop_start()
    assert refused.wait(5), "the broker let an anonymous client in"
    anon.loop_stop()

    hist = Historian(tmp_path / "fleet.db")
    fleet = Fleet(hist, port=port, group="mine", client_id="fleet-tls", username="fleet",
                  password=USERS["fleet"], tls=True, tls_ca=str(tmp_path / "pki" / "ca.pem"))
    fleet.start()
    assert fleet.connected.wait(10), "the fleet consumer did not connect over TLS"
    time.sleep(0.2)
    rig = station(tmp_path / "s", port, "shaft-tls", USERS["ropemon"])
    (face,) = start_faces(rig.stations, rig.file)
    try:
        wait(lambda: face.connected and face.sessions == 1, what="the station connected over TLS")
        assert "(TLS)" in face.describe()
        for k in range(20):
            rig.feed("h0", (5000 + k, 5000, 5000, 5000))
        wait(lambda: hist.conn.execute("SELECT COUNT(*) FROM tension").fetchone()[0] == 20 * 4,
             what="the fleet's historian over TLS")
    finally:
        face.stop()
        rig.close()
        fleet.stop()
    got = hist.conn.execute("SELECT frame_seq, tension_kn FROM tension WHERE rope = 1 ORDER BY frame_seq").fetchall()
    assert got == [(k + 1, (5000 + k) / 100) for k in range(20)]
    assert fleet.stats["births"] >= 1
    hist.close()


def test_a_wrong_password_is_refused_and_said_without_a_station_fault(tmp_path, tls_broker, caplog):
    caplog.set_level(logging.WARNING, logger="ropemon.station.mqtt")
    rig = station(tmp_path / "s", tls_broker.port, "shaft-bad", "not-the-password")
    (face,) = start_faces(rig.stations, rig.file)
    try:
        wait(lambda: face.last_error is not None and "refused" in face.last_error, what="the refusal")
        assert not face.connected and face.sessions == 0
        why = face.last_error
        assert "the broker refused the connection" in why and "Not authorized" in why
        assert "user 'ropemon'" in why and "mqtt.password_file" in why
        assert why in face.describe()
        assert face.error is None                        # not a station fault: the hoist does not depend on it
        hoist = rig.stations.hoists["h0"]
        mqtt_listener = next(x for x in hoist.pipeline.listeners if getattr(x, "name", "") == "mqtt")
        assert mqtt_listener.health() is None
        time.sleep(1.5)                                  # retried, said once
        assert caplog.text.count("the broker refused the connection") == 1
        rig.feed("h0")
        wait(lambda: face.outbox.rows == 1, what="the frame kept for when the broker lets it in")
    finally:
        face.stop()
        rig.close()


def test_a_broker_certificate_the_station_cannot_verify_is_said(tmp_path, tls_broker, caplog):
    caplog.set_level(logging.WARNING, logger="ropemon.station.mqtt")
    rig = station(tmp_path / "s", tls_broker.port, "shaft-noca", USERS["ropemon"], tls_ca=False)
    (face,) = start_faces(rig.stations, rig.file)
    try:
        wait(lambda: face.last_error is not None, what="the TLS failure")
        assert "cannot connect to 127.0.0.1" in face.last_error
        assert "CERTIFICATE_VERIFY_FAILED" in face.last_error, face.last_error
        assert face.error is None and not face.connected
    finally:
        face.stop()
        rig.close()

