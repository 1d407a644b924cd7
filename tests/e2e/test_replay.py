"""`ropemon replay`: the firmware in micropython (and CPython) on a sensor stream."""
import json
import struct
from pathlib import Path

import pytest

from ropemon.cli import main
from ropemon.lab.demo import read_frames_bin
from ropemon.firmware import FIRMWARE_DIR
from ropemon.station.protocol import L

CONFIG = FIRMWARE_DIR / "node.json"


def rsens(path, samples=400, ropes=4, hz=200):
    head = struct.pack("<4sHHHH", b"RSNS", 1, ropes, hz, 0)
    rec = [20000] * ropes + [30000] * ropes + [40000, 0xFFFF, 0, 0]
    path.write_bytes(head + struct.pack("<%dH" % len(rec), *rec) * samples)
    return path


@pytest.mark.parametrize("interp", ["micropython", "cpython"])
def test_replay_writes_one_frame_per_window(tmp_path, capsys, interp):
    doc = json.loads(CONFIG.read_text())
    phys, nd = doc["physical"], doc["node"]
    window = phys["sample_hz"] // phys["frame_hz"]
    out = tmp_path / "f.bin"
    assert main(["replay", str(rsens(tmp_path / "s.rsens", samples=10 * window, hz=phys["sample_hz"])),
                 "--out", str(out), "--interpreter", interp]) == 0
    assert "-> 10 frames" in capsys.readouterr().out
    sent = read_frames_bin(out, {nd["node_id"]: bytes(nd["key"])})
    assert [f.seq for f in sent.frames] == list(range(10))
    assert all(f.kind == L.KIND_DATA and len(f.ropes) == phys["ropes"] for f in sent.frames)


def test_refused_config_gives_status_frames_and_says_why(tmp_path, capsys):
    doc = json.loads(CONFIG.read_text())
    doc["crc"] ^= 1
    bad = tmp_path / "node.json"
    bad.write_text(json.dumps(doc))
    out = tmp_path / "f.bin"
    assert main(["replay", str(rsens(tmp_path / "s.rsens", samples=100)), "--out", str(out),
                 "--config", str(bad)]) == 0
    assert "crc" in capsys.readouterr().err.lower()
    frames = read_frames_bin(out).frames
    assert frames and all(f.kind == L.KIND_STATUS and f.status & L.ST_CONFIG_FAULT for f in frames)


def test_bad_inputs_are_refused_with_the_reason(tmp_path, capsys):
    junk = tmp_path / "junk.rsens"
    junk.write_bytes(b"hello world, not a stream")
    assert main(["replay", str(junk), "--out", str(tmp_path / "o.bin")]) == 1
    assert "not a sensor stream" in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "missing.rsens"), "--out", str(tmp_path / "o.bin")]) == 1
    assert "cannot read" in capsys.readouterr().err
    s = rsens(tmp_path / "s.rsens", samples=10)
    assert main(["replay", str(s), "--out", str(tmp_path / "o.bin"), "--config", str(tmp_path / "nope.json")]) == 1
    assert "no such config file" in capsys.readouterr().err
    three = rsens(tmp_path / "three.rsens", samples=10, ropes=3)
    assert main(["replay", str(three), "--out", str(tmp_path / "o.bin")]) == 1
    assert "3 ropes" in capsys.readouterr().err


# ---------------------------------------------------------------- --db: the station's data path

SCENARIOS = FIRMWARE_DIR.parent / "scenarios"


@pytest.fixture(scope="module")
def wind(tmp_path_factory):
    """short-test, but a 12 m creep (a trip for the report) and a 4 s rest after it (the trip ends)."""
    d = tmp_path_factory.mktemp("wind")
    text = (SCENARIOS / "short-test.toml").read_text()
    text = text.replace('site = "paper-site.toml"', f'site = "{SCENARIOS / "paper-site.toml"}"')
    text = text.replace("to_depth_m = 5.0", "to_depth_m = 14.0")
    text = text.replace('duration_s = 1.0\nlabel = "rest below the landing"',
                        'duration_s = 4.0\nlabel = "rest below the landing"')
    (d / "wind.toml").write_text(text)
    assert main(["simulate", str(d / "wind.toml"), "--out", str(d / "sim")]) == 0
    return d / "sim"


def rows(path):
    import csv
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_replay_into_a_log_that_report_and_export_read(wind, tmp_path, capsys):
    db, out = tmp_path / "wind.db", tmp_path / "f.bin"
    capsys.readouterr()
    assert main(["replay", str(wind / "sensors.rsens"), "--config", str(wind / "node.json"),
                 "--db", str(db), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    sent = read_frames_bin(out).frames
    assert len(sent) > 100
    assert f"{db}: {len(sent)} frames stored, 1 trips" in text
    kinds = [ln.split()[0] for ln in text.split("alarm events:")[1].splitlines()[2:] if ln.startswith("    ")]
    assert "deviation" not in kinds                 # a balanced hoist at rest and creeping
    assert main(["report", str(db), "--config", str(wind / "node.json"), "--out", str(tmp_path / "rep")]) == 0
    report = capsys.readouterr().out
    assert "trip 1 (node 1): " in report and "rope 4" in report and "sum" in report
    assert main(["export", str(db), "--out", str(tmp_path / "csv")]) == 0
    frames = rows(tmp_path / "csv" / "frames.csv")
    assert [int(r["seq"]) for r in frames] == [f.seq for f in sent]
    assert all(r["receiver"] == "replay" and r["authenticated"] == "1" for r in frames)
    # the station's clock was the node's: rx_time is the frame's node time
    assert [float(r["rx_time"]) for r in frames] == pytest.approx([f.time_ms / 1000 for f in sent])
    trips = rows(tmp_path / "csv" / "trips.csv")
    assert len(trips) == 1 and trips[0]["end_time"] != ""
    assert float(trips[0]["end_time"]) < sent[-1].time_ms / 1000


def test_an_imbalanced_rope_raises_the_deviation_alarm_on_node_time(wind, tmp_path, capsys):
    """Rope 2's cylinder area 30 % too large in the config: the node reads it ~+21 % from the
    mean from the first frame, so DEVIATION rope 2 raises after its 0.5 s hold of node time."""
    from ropemon.commission.nodejson import make_node_json
    from ropemon.station.store import Store

    doc = json.loads((wind / "node.json").read_text())
    doc["physical"]["cylinder_area_m2"][1] *= 1.3
    cfg = tmp_path / "imbalanced.json"
    cfg.write_text(json.dumps(make_node_json(doc["physical"], node_id=doc["node"]["node_id"],
                                             key=bytes(doc["node"]["key"]))))
    db = tmp_path / "imb.db"
    capsys.readouterr()
    assert main(["replay", str(wind / "sensors.rsens"), "--config", str(cfg), "--db", str(db)]) == 0
    text = capsys.readouterr().out
    assert ["deviation", "1", "0"] in [ln.split() for ln in text.splitlines()]
    assert "deviation:n1:r1" in text.split("raised at the end:")[1]
    with Store(db) as st:
        events = [e for e in st.events() if e["kind"] == "deviation"]
        first = st.frames()[0].frame.time_ms / 1000
    assert [(e["action"], e["alarm"], e["rope"]) for e in events] == [("raise", "deviation:n1:r1", 1)]
    assert events[0]["value"] == pytest.approx(0.21, abs=0.02)
    assert events[0]["time_s"] == pytest.approx(first + 0.5)


def test_db_refusals_name_the_reason(wind, tmp_path, capsys):
    s = str(wind / "sensors.rsens")
    assert main(["replay", s]) == 2
    assert "give --out FRAMES.bin, --db FILE or both" in capsys.readouterr().err
    db = tmp_path / "old.db"
    db.write_text("")
    assert main(["replay", s, "--config", str(wind / "node.json"), "--db", str(db)]) == 1
    assert "exists; --db writes a new log" in capsys.readouterr().err
    from ropemon.commission.nodejson import seal
    doc = json.loads((wind / "node.json").read_text())
    del doc["node"]["key"]
    cfg = tmp_path / "nokey.json"
    cfg.write_text(json.dumps(seal(doc)))
    out = tmp_path / "n.bin"
    assert main(["replay", s, "--config", str(cfg), "--db", str(tmp_path / "n.db"), "--out", str(out)]) == 1
    assert "nokey.json: node.key: must be 16..32 bytes" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "n.db").exists()   # refused before the firmware ran


def test_db_says_and_fails_when_the_decoder_refuses_frames(wind, tmp_path, capsys, monkeypatch):
    """The log is built from the node's own bytes: a frame the decoder refuses (here one byte
    of the third frame flipped after the firmware wrote it) leaves it incomplete, and the
    command says so and fails."""
    from ropemon.commission import replay as rp
    real = rp.replay

    def corrupting(sensors, out, config, interpreter):
        fig = real(sensors, out, config, interpreter)
        data = bytearray(Path(out).read_bytes())
        third = [i for i, b in enumerate(data) if b == 0][4]   # frames are 0x00 .. 0x00
        data[third + 5] ^= 0x40
        Path(out).write_bytes(bytes(data))
        return fig

    monkeypatch.setattr(rp, "replay", corrupting)
    db = tmp_path / "bad.db"
    assert main(["replay", str(wind / "sensors.rsens"), "--config", str(wind / "node.json"), "--db", str(db)]) == 1
    cap = capsys.readouterr()
    assert "1 frames refused by the decoder" in cap.out and "lacks them" in cap.err
