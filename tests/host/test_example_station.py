"""examples/station.toml: the example station file parses with the station's own parsers, holds
every key they read and no other, documents every key, has every face, and `ropemon serve`
starts every face on a copy of it."""
from __future__ import annotations

import json
import re
import secrets
import signal
import socket
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import pytest

from ropemon.station import tomlfields
from ropemon.station import faces
from ropemon.station.stationfile import load_station_file

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "station.toml"
DOCS = [ROOT / "docs" / "web.md", ROOT / "docs" / "integration.md"]
#: "# key = value  # ...": an alternative the example leaves off (a key, not prose)
ALTERNATIVE = re.compile(r'^# ?([A-Za-z_][A-Za-z0-9_-]*|"[^"]+") = ')
KEY_LINE = re.compile(r'^([A-Za-z_][A-Za-z0-9_-]*|"[^"]+") = ')


def parse_faces(sf) -> None:
    """Every face table through its own module's parser (as its `start` does), which refuses
    unknown keys; a face without a parser here fails the test."""
    from ropemon.station import modbus, mqtt, opcua
    parsers = {
        "web": lambda table: None,                  # checked by stationfile itself (StationConfig.web)
        "opcua": lambda table: opcua.parse_table(table, sf.path.parent),
        "modbus": modbus.parse_table,
        "mqtt": lambda table: mqtt.parse_table(table, sf.path.parent),
    }
    assert set(parsers) == set(faces.FACES), "a face without a parser in this test"
    for name, table in faces.configured(sf).items():
        parsers[name](table)


def parsed_tables(path: Path, monkeypatch) -> list[tuple[str, set, set]]:
    """(table name, keys in the file, keys the parser read) of every table the parsers finish."""
    seen: list[tuple[str, set, set]] = []
    finish = tomlfields.Table.finish

    def recording(self):
        seen.append((self.name, set(self.data), set(self.used)))
        finish(self)

    with monkeypatch.context() as m:
        m.setattr(tomlfields.Table, "finish", recording)
        parse_faces(load_station_file(path))
    return seen


def with_alternatives(text: str) -> str:
    """The example with its "# key = value" alternatives taken in."""
    return "\n".join(line[1:].lstrip() if ALTERNATIVE.match(line) else line for line in text.splitlines()) + "\n"


@pytest.mark.parametrize("alternatives", [False, True], ids=["as set", "with the alternatives"])
def test_the_example_parses_and_holds_exactly_the_keys_the_parsers_read(tmp_path, monkeypatch, alternatives):
    path = EXAMPLE
    if alternatives:
        path = tmp_path / "station.toml"
        path.write_text(with_alternatives(EXAMPLE.read_text()))
        assert path.read_text() != EXAMPLE.read_text()
    tables = parsed_tables(path, monkeypatch)
    names = {name for name, _, _ in tables}
    assert {"", "station", "hoist[0]", "hoist[1]", "web", "opcua", "modbus", "mqtt", "mqtt.deadband"} <= names
    for name, in_file, read in tables:
        assert in_file <= read, f"{name}: keys no parser reads: {sorted(in_file - read)}"
        assert read <= in_file, f"{name}: keys the parser reads that the example leaves out: {sorted(read - in_file)}"
    from ropemon.station.mqtt import DEADBANDS
    deadband = next(in_file for name, in_file, _ in tables if name == "mqtt.deadband")
    assert deadband == set(DEADBANDS)
    if alternatives:   # the optional keys read only when present
        sf = load_station_file(path)
        assert sf.web.tls_cert is not None and sf.web.tls_key is not None
        assert {"tls_cert", "tls_key"} <= set(sf.sections["mqtt"])


def test_every_key_of_the_example_is_documented_on_its_line():
    undocumented = [line for line in EXAMPLE.read_text().splitlines()
                    if (KEY_LINE.match(line) or ALTERNATIVE.match(line))
                    and not re.search(r"\s#\s+\S", line.split("=", 1)[1])]
    assert not undocumented


def _tables(doc: dict, prefix: str = ""):
    """(dotted name, table) of every table of a TOML document, arrays of tables by their name."""
    for key, value in doc.items():
        items = value if isinstance(value, list) and value and all(isinstance(v, dict) for v in value) else [value]
        for v in items:
            if isinstance(v, dict):
                name = f"{prefix}{key}"
                yield name, v
                if name != "hoist":
                    yield from _tables(v, name + ".")


def test_every_face_and_key_the_docs_show_is_in_the_example():
    example = tomllib.loads(EXAMPLE.read_text())
    sf = load_station_file(EXAMPLE)
    assert set(faces.configured(sf)) == set(faces.FACES)
    have: dict[str, set] = {}
    for name, table in _tables(example):
        have.setdefault(name, set()).update(table)
    shown = 0
    for doc in DOCS:
        for block in re.findall(r"```toml\n(.*?)```", doc.read_text(), re.S):
            for name, table in _tables(tomllib.loads(block)):
                shown += 1
                assert name in have, f"{doc.name}: [{name}] is not in the example"
                missing = sorted(set(table) - have[name])
                assert not missing, f"{doc.name}: [{name}] {missing} not in the example"
    assert shown >= 6   # web.md: station, hoist, web; integration.md: modbus, opcua, mqtt


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ca_pem() -> bytes:
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "mine test CA")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now)
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .sign(key, hashes.SHA256()))
    return cert.public_bytes(serialization.Encoding.PEM)


def test_ropemon_serve_starts_every_face_on_a_copy_of_the_example(tmp_path):
    """The example edited as a site would (its own node configs, users, the broker's login over TLS
    with its CA), on free ports of this machine's loopback: every hoist and every face starts,
    SIGTERM stops it cleanly."""
    for lib in ("starlette", "uvicorn", "asyncua", "pymodbus", "paho.mqtt", "cryptography"):
        pytest.importorskip(lib)
    from ropemon.commission.nodejson import example_physical, make_node_json
    from ropemon.station.users import add_user

    text = EXAMPLE.read_text()
    ports = {k: _free_port() for k in ("web", "opcua", "modbus", "mqtt", "gateway")}
    for old, new in [('"opc.tcp://127.0.0.1:4840/ropemon"', f'"opc.tcp://127.0.0.1:{ports["opcua"]}/ropemon"'),
                     ("port = 8080 ", f"port = {ports['web']} "), ("port = 5020 ", f"port = {ports['modbus']} "),
                     ("port = 1883 ", f"port = {ports['mqtt']} "),
                     ("socket://127.0.0.1:4001", f"socket://127.0.0.1:{ports['gateway']}"),
                     ('configs = ["../firmware/node.json"]  # node.json of each cage node',
                      'configs = ["north-skip-a.json", "north-skip-b.json"]  # node.json of each cage node'),
                     ('configs = ["../firmware/node.json"]  # one cage node', 'configs = ["south-cage.json"]  # one'),
                     ('username = ""', 'username = "shaft-2"'), ('password_file = ""', 'password_file = "mqtt-password"'),
                     ("tls = false", "tls = true")]:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    station = tmp_path / "station.toml"
    station.write_text(text)
    sf = load_station_file(station)
    for h in sf.hoists:
        for node, config in enumerate(h.configs, start=1):
            config.write_text(json.dumps(make_node_json(example_physical(), node_id=node, key=secrets.token_bytes(16))))
    add_user(sf.web.users, "olga", "operator", secrets.token_urlsafe(12))
    pw = tmp_path / "mqtt-password"
    pw.write_text(secrets.token_urlsafe(12) + "\n")
    pw.chmod(0o600)
    (tmp_path / "pki").mkdir()
    (tmp_path / "pki" / "mine-ca.pem").write_bytes(_ca_pem())

    t0 = time.monotonic()
    p = subprocess.Popen([sys.executable, "-m", "ropemon.cli", "serve", str(station)],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(p.stderr.readline, "")), daemon=True)
    reader.start()
    wanted = ("ropemon serve: web: ", "ropemon serve: OPC UA on ", "ropemon serve: Modbus TCP on ",
              "ropemon serve: MQTT Sparkplug B to ")
    try:
        while time.monotonic() - t0 < 30 and p.poll() is None:      # about 5 s on a 2-core machine
            if all(any(ln.startswith(w) for ln in lines) for w in wanted):
                break
            time.sleep(0.05)
    finally:
        p.send_signal(signal.SIGTERM)
        rc = p.wait(timeout=20)
        reader.join(5)
    err = "".join(lines)
    assert rc == 0, err
    for w in wanted:
        assert w in err, f"{w!r} not on stderr:\n{err}"
    assert "2 hoists" in err and "1 user in" in err, err
    assert "(TLS)" in err and "client certificates from" in err, err
    assert sorted(q.name for q in (tmp_path / "data").glob("*.db")) == ["mqtt-outbox.db", "north.db", "south.db"]
