"""The station file (station.toml) and a station of several hoists built from it."""
from __future__ import annotations

import json

import pytest

from ropemon.commission.nodejson import example_physical, make_node_json
from ropemon.station.hoists import Station
from ropemon.station.protocol import encode_frame
from ropemon.station.stationfile import StationConfigError, load_station_file

KEY_N, KEY_S = bytes(range(16)), bytes(range(1, 17))


def write(tmp_path, text: str):
    p = tmp_path / "station.toml"
    p.write_text(text)
    return p


def node_json(tmp_path, name: str, node: int, key: bytes) -> str:
    (tmp_path / name).write_text(json.dumps(make_node_json(example_physical(), node_id=node, key=key)))
    return name


GOOD = """
[station]
name = "No. 2 shaft"
data_dir = "data"
silent_s = 3

[[hoist]]
id = "north"
name = "North shaft"
configs = ["north.json"]
receivers = { pithead = "loop://", mid-shaft = "loop://" }

[[hoist]]
id = "south"
configs = ["south.json"]
receivers = { pithead = "loop://" }

[web]
port = 8099
"""


def test_a_station_of_two_hoists_each_with_its_own_station_alarms_and_log(tmp_path):
    node_json(tmp_path, "north.json", 1, KEY_N)
    node_json(tmp_path, "south.json", 1, KEY_S)       # the same node id on another hoist: its own key
    sf = load_station_file(write(tmp_path, GOOD))
    assert [h.id for h in sf.hoists] == ["north", "south"] and sf.hoists[1].name == "south"
    assert sf.hoists[0].receivers == (("pithead", "loop://"), ("mid-shaft", "loop://"))
    assert sf.web is not None and sf.web.port == 8099 and sf.web.bind == "127.0.0.1"
    clk = [100.0]
    s = Station(sf, clock=lambda: clk[0])
    try:
        s.step()                                      # the station starts looking
        north, south = s.hoists["north"], s.hoists["south"]
        north.pipeline.feed("pithead", encode_frame(node=1, seq=5, key=KEY_N, ropes=[(500, 500, 500, 0)] * 4, battery_mv=12_000)[1])
        south.pipeline.feed("pithead", encode_frame(node=1, seq=5, key=KEY_N, ropes=[(500, 500, 500, 0)] * 4, battery_mv=12_000)[1])
        assert north.pipeline.decoders["pithead"].counts.frames_ok == 1
        assert south.pipeline.decoders["pithead"].counts.mac_fail == 1   # north's key is not south's
        clk[0] = 110.0
        north.pipeline.feed("pithead", encode_frame(node=1, seq=6, key=KEY_N, ropes=[(500, 500, 500, 0)] * 4, battery_mv=12_000)[1])
        s.step()
        assert [a.id for a in south.alarms.engine.active() if a.present] == ["link_integrity:pithead",
                                                                               "silent:n1"]
        assert not [a for a in north.alarms.engine.active() if a.kind in ("silent", "link_integrity")]
    finally:
        s.close()
    assert sorted(p.name for p in (tmp_path / "data").glob("*.db")) == ["north.db", "south.db"]


@pytest.mark.parametrize("edit, message", [
    ('id = "north"', 'id = "North Shaft"', ),
    ('receivers = { pithead = "loop://" }', "receivers = { }"),
    ("silent_s = 3", "silent_s = nan"),
    ("port = 8099", 'port = "8099"'),
    ('id = "south"', 'id = "south"\nshaft_m = -3'),
    ("[web]", "[webb]"),
    ('id = "south"', 'id = "north"'),
])
def test_bad_station_files_are_refused_with_the_field(tmp_path, edit, message):
    bad = GOOD.replace(edit, message, 1)
    assert bad != GOOD
    with pytest.raises(StationConfigError) as e:
        load_station_file(write(tmp_path, bad))
    field = {"North Shaft": "hoist[0].id", "receivers": "hoist[1].receivers", "nan": "station.silent_s",
             '"8099"': "web.port", "webb": "webb", 'id = "north"': "hoist[1].id", "shaft_m": "hoist[1].shaft_m"}
    assert any(k in message and v in str(e.value) for k, v in field.items()), str(e.value)


def test_ropemon_serve_runs_the_hoists_and_prints_their_alarms_with_the_hoist(tmp_path):
    """`ropemon serve` with no faces: every hoist's station runs; a node never heard on the
    south hoist is an alarm line naming the hoist; SIGTERM stops it cleanly."""
    import signal
    import subprocess
    import sys
    import time

    node_json(tmp_path, "north.json", 1, KEY_N)
    node_json(tmp_path, "south.json", 1, KEY_S)
    station = write(tmp_path, GOOD.replace("silent_s = 3", "silent_s = 1").replace("[web]\nport = 8099\n", ""))
    p = subprocess.Popen([sys.executable, "-m", "ropemon.cli", "serve", str(station)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = []
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and len({(ln["hoist"], ln["id"]) for ln in lines}) < 2:
            line = p.stdout.readline()
            if not line:
                break
            lines.append(json.loads(line))
    finally:
        p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=20)
    assert p.returncode == 0, err
    assert {(ln["hoist"], ln["id"]) for ln in lines if ln["event"] == "raise"} >= {("north", "silent:n1"),
                                                                                   ("south", "silent:n1")}


def test_ropemon_serve_says_where_each_hoists_replay_protection_resumed(tmp_path):
    """A restarted `ropemon serve` prints, per hoist with frames in its log, the replay
    protection it resumed from it, as `ropemon monitor` does; a hoist with none: nothing."""
    import signal
    import subprocess
    import sys
    import time

    from ropemon.station.decoder import SEQ_COUNT_BITS

    node_json(tmp_path, "north.json", 1, KEY_N)
    node_json(tmp_path, "south.json", 1, KEY_S)
    station = write(tmp_path, GOOD.replace("silent_s = 3", "silent_s = 1").replace("[web]\nport = 8099\n", ""))
    s = Station(load_station_file(station))
    try:                                              # the first run: north logs boot 3, counts 1..5
        for k in range(1, 6):
            s.hoists["north"].pipeline.feed("pithead", encode_frame(
                node=1, seq=3 << SEQ_COUNT_BITS | k, key=KEY_N, ropes=[(500, 500, 500, 0)] * 4, battery_mv=12_000)[1])
    finally:
        s.close()
    err_path = tmp_path / "stderr.txt"
    with open(err_path, "w") as err:
        p = subprocess.Popen([sys.executable, "-m", "ropemon.cli", "serve", str(station)],
                             stdout=subprocess.PIPE, stderr=err, text=True)
        try:
            deadline = time.monotonic() + 20
            first = p.stdout.readline()                   # an alarm line: the start is behind it
            assert first and time.monotonic() < deadline
        finally:
            p.send_signal(signal.SIGTERM)
            p.communicate(timeout=20)
    text = err_path.read_text()
    assert p.returncode == 0, text
    assert "ropemon serve: hoist north: resumed replay protection from the log: node 1 at boot 3 count 5" in text
    assert "hoist south" not in text


def test_a_station_set_takes_other_receivers_for_a_hoist(tmp_path):
    """The demo points a hoist at its virtual ports instead of the station file's adapters."""
    node_json(tmp_path, "north.json", 1, KEY_N)
    node_json(tmp_path, "south.json", 1, KEY_S)
    sf = load_station_file(write(tmp_path, GOOD.replace('data_dir = "data"\n', "").replace(
        'id = "south"', 'id = "south"\nshaft_m = 806')))
    assert sf.hoist("south").shaft_m == 806.0 and sf.hoist("north").shaft_m is None
    s = Station(sf, receivers={"south": [("radio", "loop://")]})
    try:
        assert s.hoists["south"].config.receivers == (("radio", "loop://"),)
        assert s.hoists["north"].config.receivers == sf.hoists[0].receivers
        s.start()
        assert sorted(s.hoists["south"].pipeline.hub.receivers) == ["radio"]
    finally:
        s.close()
    with pytest.raises(ValueError, match="west"):
        Station(sf, receivers={"west": [("radio", "loop://")]})


def test_ropemon_serve_on_a_taken_port_says_which_face_and_exits_2(tmp_path):
    """A face that cannot listen (its port taken by another program) stops the start with one
    line naming the face and the reason, exit 2: no traceback."""
    import socket
    import subprocess
    import sys

    node_json(tmp_path, "north.json", 1, KEY_N)
    node_json(tmp_path, "south.json", 1, KEY_S)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        station = write(tmp_path, GOOD.replace("[web]\nport = 8099\n", f"[modbus]\nport = {port}\n"))
        p = subprocess.run([sys.executable, "-m", "ropemon.cli", "serve", "--quiet", str(station)],
                           capture_output=True, text=True, timeout=60)
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr, p.stderr
    assert "ropemon serve: [modbus]: cannot start:" in p.stderr, p.stderr
