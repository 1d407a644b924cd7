"""Every command that reads a file refuses a bad one: a clear error, never a traceback or a hang.

For each file argument of each command (a "slot": `ropemon decode FILE`, `ropemon config
SITE.toml`, the key_file SITE.toml names, ...) a corpus of bad files is made in tmp_path:
the faults any file can have (missing, empty, binary junk, truncated, huge as a sparse file,
a FIFO, a directory, /dev/zero) and those of its format (nesting deep enough to break the
parser, wrong types, NaN and infinity, strings for numbers, unknown tables, a 5 MB CSV field,
numbers that would run for ever, ...). Each case runs `ropemon.cli.main` in this process,
under a SIGALRM watchdog (a hang fails the case), and checks:

- the exit status the command gives bad input (2: decode, monitor, report, export,
  fit-compliance, study; 1 where the command always used 1: config, fit-friction, simulate,
  replay, deploy, demo, evaluate; and 1 for a decode that read its input but decoded no frame),
- stderr names the file (or, for a field of a good file, the field) and the reason,
- no traceback, and no exception escapes `main`.

The limits are ropemon.station.files's (docs/operator.md, "Input files").
"""
from __future__ import annotations

import json
import os
import random
import re
import shutil
import signal
import sqlite3
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from ropemon import cli
from ropemon.station import files
from ropemon.station.protocol import encode_frame
from ropemon.station.store import Store

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "scenarios"
WATCHDOG_S = 30


class Hung(Exception):
    """The command did not finish within WATCHDOG_S."""


def _alarm(signum, frame):
    raise Hung(f"no answer within {WATCHDOG_S} s: the command hangs on this input")


def run_cli(argv: list, capsys) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of `ropemon ARGV` run in this process."""
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(WATCHDOG_S)
    try:
        try:
            rc = cli.main([str(a) for a in argv])
        except SystemExit as e:  # argparse: usage errors
            rc = e.code if isinstance(e.code, int) else 2
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    out, err = capsys.readouterr()
    return rc, out, err


# ---------------------------------------------------------------- good inputs, to spoil


@dataclass
class Good:
    dir: Path
    site: Path
    node_json: Path
    friction: Path
    compliance: Path
    scenario: Path
    rsens: Path
    capture: Path
    db: Path
    csv: Path
    key: Path
    sample_hz: int
    ropes: int


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Good:
    d = tmp_path_factory.mktemp("good")
    for name in ("paper-site.toml", "paper-friction.json", "paper-compliance.json"):
        shutil.copy(SCENARIOS / name, d / name)
    site = d / "paper-site.toml"
    for name in ("short-test.toml", "duty-cycle.toml"):   # naming the site by its full path: copies work anywhere
        text = (SCENARIOS / name).read_text()
        assert 'site = "paper-site.toml"' in text
        (d / name).write_text(text.replace('site = "paper-site.toml"', f'site = "{site}"'))
    node_json = d / "node.json"
    assert cli.main(["config", str(site), "--out", str(node_json)]) == 0
    doc = json.loads(node_json.read_text())
    ph = doc["physical"]
    ropes, hz = int(ph["ropes"]), int(ph["sample_hz"])
    rsens = d / "good.rsens"
    words = [30000] * (2 * ropes) + [60000, 0xFFFF, 0, 0]
    rsens.write_bytes(struct.pack("<4sHHHH", b"RSNS", 1, ropes, hz, 0)
                      + struct.pack(f"<{len(words)}H", *words) * 20)
    capture = d / "good.bin"   # signed with the site's key: node.json's
    key = bytes.fromhex("00112233445566778899aabbccddeeff")
    assert 'key_hex = "00112233445566778899aabbccddeeff"' in site.read_text()
    capture.write_bytes(b"".join(encode_frame(node=1, seq=k, ropes=[(1, 1, 1, 1)] * 4, key=key)[1]
                                 for k in range(10)))
    db = d / "good.db"
    Store(db).close()
    csv_path = d / "bed.csv"
    csv_path.write_text("time_s,pressure_MPa,velocity_m_s,friction_N\n"
                        + "".join(f"{k * 0.001:.3f},3.0,0.01,100.0\n" for k in range(50)))
    keyfile = d / "node.key"
    keyfile.write_text("00112233445566778899aabbccddeeff\n")
    return Good(d, site, node_json, d / "paper-friction.json", d / "paper-compliance.json",
                d / "short-test.toml", rsens, capture, db, csv_path, keyfile, hz, ropes)


def site_naming(good: Good, tmp: Path, **edits: str) -> Path:
    """A copy of the good SITE.toml in `tmp` whose lines `key = ...` are replaced (key -> new line)."""
    text = good.site.read_text()
    text = text.replace('file = "paper-friction.json"', f'file = "{good.friction}"')
    text = text.replace('file = "paper-compliance.json"', f'file = "{good.compliance}"')
    for old, new in edits.items():
        old = old.replace("__", " ")
        assert old in text, old
        text = text.replace(old, new, 1)
    p = tmp / "site.toml"
    p.write_text(text)
    return p


def scenario_naming_site(good: Good, tmp: Path, site: Path) -> Path:
    p = tmp / "scenario.toml"
    p.write_text(good.scenario.read_text().replace(f'site = "{good.site}"', f'site = "{site}"'))
    return p


# ---------------------------------------------------------------- the slots


@dataclass
class Slot:
    """One file argument of one command: `argv(bad, good, tmp)` is the command line with the
    bad file in it; `code` the exit status for bad input; `kind` its format."""

    name: str
    argv: Callable[[Path, Good, Path], list]
    code: int
    kind: str
    limit: int
    suffix: str = ""
    skip: tuple[str, ...] = ()
    content_code: int | None = None   # the status for a readable file of bad content, if not `code`
    good_file: Callable[[Good], Path] | None = None
    cases: tuple[str, ...] | None = None  # the format cases that apply (default: all of its kind)


def _port() -> list:
    return ["--port", "socket://127.0.0.1:9"]


SLOTS = [
    Slot("decode", lambda b, g, t: ["decode", b], 2, "capture", files.MAX_CAPTURE,
         skip=("truncated",), content_code=1),
    Slot("decode-config", lambda b, g, t: ["decode", g.capture, "--config", b], 2, "node", files.MAX_NODE_JSON,
         good_file=lambda g: g.node_json),
    Slot("monitor-config", lambda b, g, t: ["monitor", *_port(), "--headless", "--config", b], 2, "node",
         files.MAX_NODE_JSON, good_file=lambda g: g.node_json),
    Slot("monitor-db", lambda b, g, t: ["monitor", *_port(), "--headless", "--config", g.node_json, "--db", b], 2,
         "db", 0, skip=("missing", "empty", "huge"), good_file=lambda g: g.db),
    Slot("report", lambda b, g, t: ["report", b, "--area-m2", "0.0079", "--out", t / "rep"], 2, "db", 0,
         skip=("huge",), good_file=lambda g: g.db),
    Slot("report-config", lambda b, g, t: ["report", g.db, "--config", b, "--out", t / "rep"], 2, "node",
         files.MAX_NODE_JSON, good_file=lambda g: g.node_json),
    Slot("report-site", lambda b, g, t: ["report", g.db, "--area-m2", "0.0079", "--site", b, "--out", t / "rep"], 2,
         "site", files.MAX_SITE_TOML, good_file=lambda g: g.site),
    Slot("export", lambda b, g, t: ["export", b, "--out", t / "csv"], 2, "db", 0, skip=("huge",),
         good_file=lambda g: g.db),
    Slot("fit-friction", lambda b, g, t: ["fit-friction", b, "--out", t / "f.json"], 1, "csv", files.MAX_CSV,
         good_file=lambda g: g.csv),
    Slot("fit-compliance-node", lambda b, g, t: ["fit-compliance", b, g.rsens], 2, "node", files.MAX_NODE_JSON,
         good_file=lambda g: g.node_json),
    Slot("fit-compliance-rsens", lambda b, g, t: ["fit-compliance", g.node_json, b], 2, "rsens", files.MAX_RSENS),
    Slot("config", lambda b, g, t: ["config", b, "--out", t / "n.json"], 1, "site", files.MAX_SITE_TOML,
         good_file=lambda g: g.site),
    Slot("config-key_file", lambda b, g, t: ["config", site_naming(g, t, **{'key_hex = "00112233445566778899aabbccddeeff"':
                                                                              f'key_file = "{b}"'}),
                                             "--out", t / "n.json"], 1, "key", files.MAX_KEY_FILE,
         good_file=lambda g: g.key),
    Slot("config-friction_file", lambda b, g, t: ["config", site_naming(g, t, **{f'file = "{g.friction}"': f'file = "{b}"'}),
                                                  "--out", t / "n.json"], 1, "fit", files.MAX_FIT_JSON,
         good_file=lambda g: g.friction),
    Slot("config--friction", lambda b, g, t: ["config", g.site, "--friction", b, "--out", t / "n.json"], 1, "fit",
         files.MAX_FIT_JSON, good_file=lambda g: g.friction),
    Slot("config--compliance", lambda b, g, t: ["config", g.site, "--compliance", b, "--out", t / "n.json"], 1, "fit",
         files.MAX_FIT_JSON, good_file=lambda g: g.compliance),
    Slot("simulate", lambda b, g, t: ["simulate", b, "--out", t / "sim", "--quiet"], 1, "scenario",
         files.MAX_SCENARIO_TOML, good_file=lambda g: g.scenario),
    Slot("simulate-site", lambda b, g, t: ["simulate", scenario_naming_site(g, t, b), "--out", t / "sim", "--quiet"], 1,
         "site", files.MAX_SITE_TOML, good_file=lambda g: g.site),
    Slot("replay", lambda b, g, t: ["replay", b, "--out", t / "o.bin", "--config", g.node_json,
                                    "--interpreter", "cpython"], 1, "rsens", files.MAX_RSENS),
    Slot("replay-config", lambda b, g, t: ["replay", g.rsens, "--out", t / "o.bin", "--config", b,
                                           "--interpreter", "cpython"], 1, "node", files.MAX_NODE_JSON,
         skip=("missing",), good_file=lambda g: g.node_json,
         cases=("deep", "list")),   # a node.json the node refuses field by field is replayed: config-fault frames
    Slot("deploy-config", lambda b, g, t: ["deploy", "--port", "/nonexistent-port", "--config", b], 1, "node",
         files.MAX_NODE_JSON, good_file=lambda g: g.node_json),
    Slot("evaluate", lambda b, g, t: ["evaluate", b, "--no-firmware", "--quick"], 1, "scenario",
         files.MAX_SCENARIO_TOML, suffix=".toml", skip=("missing", "devzero"), good_file=lambda g: g.scenario),
    Slot("demo", lambda b, g, t: ["demo", "--headless", "--scenario", b, "--out", t / "demo"], 1, "scenario",
         files.MAX_SCENARIO_TOML, suffix=".toml", skip=("empty", "truncated", "devzero", "huge")),  # each runs simulate
    Slot("study", lambda b, g, t: ["study", "pithead-bound", b], 2, "run", 0,
         skip=("empty", "junk", "truncated", "huge", "devzero", "fifo")),
]

# ---------------------------------------------------------------- generic faults

ANY_READ = r"cannot read|[Nn]o such|neither a file|not a (file|regular)"
GENERIC_REASON = {
    "missing": ANY_READ,
    "fifo": r"FIFO|neither a file",   # demo: "neither a file nor scenarios/NAME.toml"
    "directory": r"directory|neither a file",
    "devzero": r"character device|larger than",   # load_node_json reads /dev/zero bounded
    "huge": r"larger than",
}
NODE_REASON = (r"not valid JSON|not JSON|nested|not a node|physical|node\b|node\.|must be|finite|sha256|digest"
               r"|changed|key|CRC|crc|field|schema|object")
CONTENT_REASON = {  # kind -> fault -> reason
    "capture": {"empty": r"no frame decoded \(empty input\)", "junk": r"no frame decoded"},
    "node": {"empty": NODE_REASON, "junk": NODE_REASON, "truncated": NODE_REASON},
    "fit": {"empty": r"not valid JSON", "junk": r"not valid JSON", "truncated": r"not valid JSON"},
    "site": {"empty": r"missing", "junk": r"not UTF-8|not text|not valid TOML", "truncated": r"not valid TOML|missing"},
    "scenario": {"empty": r"missing|must", "junk": r"not UTF-8|not text|not valid TOML",
                 "truncated": r"not valid TOML|missing"},
    "csv": {"empty": r"empty file", "junk": r"not UTF-8|not text", "truncated": r"too few records|not a number"},
    "rsens": {"empty": r"too short", "junk": r"not a (version-1 \.rsens|sensor stream)", "truncated": r"too short"},
    "db": {"empty": r"empty file", "junk": r"not an SQLite database", "truncated": r"not a usable|malformed|cannot open|not a ropemon"},
    "key": {"empty": r"hexadecimal|bytes", "junk": r"not UTF-8|not text", "truncated": r"16\.\.32 bytes"},
}
GENERIC = ("missing", "empty", "junk", "truncated", "fifo", "directory", "devzero", "huge")


def junk_bytes() -> bytes:
    return b"\x00\xff\xfe" + random.Random(7).randbytes(4093)


def make_generic(fault: str, slot: Slot, good: Good, tmp: Path) -> Path:
    """The bad file for a generic fault, at a name that is this case's own."""
    p = tmp / f"bad-{slot.name}-{fault}{slot.suffix}"
    if fault == "missing":
        return p
    if fault == "empty":
        p.write_bytes(b"")
    elif fault == "junk":
        p.write_bytes(junk_bytes())
    elif fault == "truncated":
        if slot.kind == "rsens":
            p.write_bytes(good.rsens.read_bytes()[:7])
        else:
            assert slot.good_file is not None, slot.name
            data = slot.good_file(good).read_bytes()
            p.write_bytes(data[: len(data) // 2])
    elif fault == "fifo":
        os.mkfifo(p)
    elif fault == "directory":
        p.mkdir()
    elif fault == "devzero":
        return Path("/dev/zero")
    elif fault == "huge":
        with open(p, "wb") as f:
            f.truncate(slot.limit + 1)   # sparse: nothing is written
    return p


def generic_cases():
    for slot in SLOTS:
        for fault in GENERIC:
            if fault not in slot.skip:
                yield pytest.param(slot, fault, id=f"{slot.name}-{fault}")


def check(rc: int, out: str, err: str, code: int, named: str, reason: str) -> None:
    assert "Traceback" not in err + out, err
    assert rc == code, f"exit {rc}, expected {code}: {err}"
    assert named in err, f"{named!r} not named: {err}"
    assert re.search(reason, err), f"no reason /{reason}/: {err}"


@pytest.mark.parametrize("slot,fault", list(generic_cases()))
def test_generic_bad_file_is_refused(slot, fault, good, tmp_path, capsys):
    bad = make_generic(fault, slot, good, tmp_path)
    rc, out, err = run_cli(slot.argv(bad, good, tmp_path), capsys)
    content = fault in ("empty", "junk", "truncated")
    reason = CONTENT_REASON.get(slot.kind, {}).get(fault, r".") if content else GENERIC_REASON[fault]
    code = slot.content_code if content and slot.content_code is not None else slot.code
    check(rc, out, err, code, str(bad) if fault == "devzero" else bad.name, reason)


# ---------------------------------------------------------------- format faults

DEEP_JSON = "[" * 100_000 + "]" * 100_000
DEEP_TOML_ARRAY = "x = " + "[" * 100_000 + "]" * 100_000 + "\n"
DEEP_TOML_TABLES = "[" + ".".join(["a"] * 1000) + "]\nx = 1\n"


def node_edit(path_fn: Callable[[dict], None]) -> Callable[[Good], str]:
    def make(good: Good) -> str:
        doc = json.loads(good.node_json.read_text())
        path_fn(doc)
        return json.dumps(doc)
    return make


def _set(d: dict, dotted: str, value) -> None:
    *parents, last = dotted.split(".")
    for p in parents:
        d = d[p]
    d[last] = value


# (case id, content maker (Good -> text), reason[, the slots it applies to: a field only where it is used])
KEYS_READ = ("decode-config", "monitor-config", "deploy-config")       # the node's id and key
PHYSICAL_READ = ("monitor-config", "report-config")                   # the station's figures
NODE_CASES = [
    ("deep", lambda g: DEEP_JSON, r"nested|not JSON"),
    ("deep-500", lambda g: '{"physical": ' + "[" * 500 + "]" * 500 + "}", NODE_REASON),
    ("list", lambda g: "[1, 2]", NODE_REASON),
    ("nan-literal", lambda g: g.node_json.read_text().replace('"battery_low_V": 3.4', '"battery_low_V": NaN'),
     NODE_REASON, PHYSICAL_READ),
    ("battery-string", node_edit(lambda d: _set(d, "physical.battery_low_V", "3.4")), NODE_REASON, PHYSICAL_READ),
    ("node-id-inf", lambda g: g.node_json.read_text().replace('"node_id": 1', '"node_id": 1e999'), NODE_REASON,
     KEYS_READ),
    ("node-id-string", node_edit(lambda d: _set(d, "node.node_id", "1")), NODE_REASON, ("deploy-config",)),
    ("no-physical", node_edit(lambda d: d.pop("physical")), NODE_REASON,
     ("decode-config", "monitor-config", "report-config", "fit-compliance-node")),
    ("physical-list", node_edit(lambda d: _set(d, "physical", [1, 2])), NODE_REASON,
     ("decode-config", "monitor-config", "report-config", "fit-compliance-node")),
]
FIT_CASES = [
    ("deep", lambda g: DEEP_JSON, r"nested|not valid JSON"),
    ("list", lambda g: "[1, 2]", r"must be an object|not an object|friction|compliance"),
    ("string-numbers", lambda g: re_all_numbers(g), r"must be a number|missing|not a list|must be"),
]
SITE_CASES = [
    ("deep-array", lambda g: DEEP_TOML_ARRAY, r"nested"),
    ("deep-tables", lambda g: DEEP_TOML_TABLES, r"nested"),
    ("battery-string", lambda g: g.site.read_text().replace("battery_low_V = 3.40", 'battery_low_V = "3.40"'),
     r"alarms\.battery_low_V: must be a number"),
    ("node-id-inf", lambda g: g.site.read_text().replace("id = 1\n", "id = inf\n", 1), r"node\.id: must be an integer"),
    ("shaft-nan", lambda g: g.site.read_text().replace("shaft_depth_m = 810.0", "shaft_depth_m = nan"),
     r"hoist\.shaft_depth_m: must be finite"),
    ("shaft-inf", lambda g: g.site.read_text().replace("shaft_depth_m = 810.0", "shaft_depth_m = 1e999"),
     r"hoist\.shaft_depth_m: must be finite|not valid TOML"),
    ("ropes-string", lambda g: g.site.read_text().replace("ropes = 4", 'ropes = "4"', 1), r"hoist\.ropes: must be an integer"),
    ("unknown-table", lambda g: g.site.read_text() + "\n[bogus]\nx = 1\n", r"bogus: unknown field"),
    ("unknown-key", lambda g: g.site.read_text().replace("[hoist]\n", "[hoist]\nbogus = 1\n"), r"hoist\.bogus: unknown field"),
    ("ropes-float", lambda g: g.site.read_text().replace("ropes = 4", "ropes = 4.0", 1), r"hoist\.ropes: must be an integer"),
]
SCENARIO_CASES = [
    ("deep-array", lambda g: DEEP_TOML_ARRAY, r"nested"),
    ("deep-tables", lambda g: DEEP_TOML_TABLES, r"nested"),
    ("duration-1e9", lambda g: scenario_edit(g, "duration_s = 0.5", "duration_s = 1e9"),
     r"trip\.phase\[0\]\.duration_s: must be <= 21600"),
    ("duration-string", lambda g: scenario_edit(g, "duration_s = 0.5", 'duration_s = "0.5"'),
     r"trip\.phase\[0\]\.duration_s: must be a number"),
    ("duration-nan", lambda g: scenario_edit(g, "duration_s = 0.5", "duration_s = nan"), r"duration_s: must be finite"),
    ("duration-inf", lambda g: scenario_edit(g, "duration_s = 0.5", "duration_s = inf"), r"duration_s: must be finite"),
    ("step-tiny", lambda g: scenario_edit(g, 'seed = 1\n', 'seed = 1\nstep_s = 5e-9\n'), r"step_s: .*grid points"),
    ("duty-forever", lambda g: duty(g, "trips = 10\n", "trips = 10000\n"), r"duty: the phases last"),
    ("duty-rest-1e9", lambda g: duty(g, "rest_s = [8.0, 20.0]", "rest_s = [8.0, 1e9]"), r"duty\.rest_s: high must be <="),
    ("unknown-table", lambda g: g.scenario.read_text() + "\n[bogus]\nx = 1\n", r"bogus: unknown field"),
    ("rig-number", lambda g: g.scenario.read_text().replace('rig = "hoist"', "rig = 5"), r"rig: must be a string"),
    ("site-missing", lambda g: g.scenario.read_text().replace(f'site = "{g.site}"', 'site = "absent.toml"'),
     r"site \(absent\.toml\).*cannot read"),
]
CSV_CASES = [
    ("field-5MB", lambda g: "time_s,pressure_MPa,velocity_m_s,friction_N\n1,2,3,4\n" + "9" * 5_000_000 + ",1,1,1\n",
     r":3: a field longer than"),
    ("nul", lambda g: "time_s,pressure_MPa,velocity_m_s,friction_N\n1,2,\x003,4\n", r"not text|NUL"),
    ("nan", lambda g: g.csv.read_text().replace("3.0,0.01,100.0", "nan,0.01,100.0", 1), r"pressure_MPa is nan"),
    ("inf", lambda g: g.csv.read_text().replace("3.0,0.01,100.0", "3.0,inf,100.0", 1), r"velocity_m_s is inf"),
    ("string", lambda g: g.csv.read_text().replace("3.0,0.01,100.0", "three,0.01,100.0", 1), r"not a number"),
    ("no-columns", lambda g: "a,b,c\n1,2,3\n", r"missing column"),
    ("quote", lambda g: 'time_s,pressure_MPa,velocity_m_s,friction_N\n"1,2,3,4\n', r"too few records|not a number|CSV"),
    ("header-only", lambda g: "time_s,pressure_MPa,velocity_m_s,friction_N\n", r"too few records"),
]
RSENS_CASES = [
    ("magic", lambda g: b"XXXX" + g.rsens.read_bytes()[4:], r"not a (version-1 \.rsens|sensor stream)"),
    ("version", lambda g: g.rsens.read_bytes()[:4] + struct.pack("<H", 9) + g.rsens.read_bytes()[6:],
     r"version"),
    ("ropes-0", lambda g: g.rsens.read_bytes()[:6] + struct.pack("<H", 0) + g.rsens.read_bytes()[8:], r"0 ropes"),
    ("ropes-99", lambda g: g.rsens.read_bytes()[:6] + struct.pack("<H", 99) + g.rsens.read_bytes()[8:], r"99 ropes"),
]
CAPTURE_CASES = [
    ("zeros", lambda g: b"\x00" * 100_000, r"no frame decoded"),
    ("text", lambda g: b"hello, this is not a capture\n" * 100, r"no frame decoded"),
]
KEY_CASES = [
    ("not-hex", lambda g: "zz" * 16, r"hexadecimal"),
    ("too-long", lambda g: "00" * 64, r"16\.\.32 bytes"),
]


def re_all_numbers(g: Good) -> str:
    """The friction fit with every number a string."""
    def walk(v):
        if isinstance(v, dict):
            return {k: walk(x) for k, x in v.items()}
        if isinstance(v, list):
            return [walk(x) for x in v]
        return str(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v
    return json.dumps(walk(json.loads(g.friction.read_text())))


def scenario_edit(g: Good, old: str, new: str) -> str:
    text = g.scenario.read_text()
    assert old in text, old
    return text.replace(old, new, 1)


def duty(g: Good, old: str, new: str) -> str:
    """The duty-cycle scenario with the line `old` replaced by `new`."""
    text = (g.dir / "duty-cycle.toml").read_text()
    assert old in text, old
    return text.replace(old, new, 1)


FORMAT_CASES = {"node": NODE_CASES, "fit": FIT_CASES, "site": SITE_CASES, "scenario": SCENARIO_CASES,
                "csv": CSV_CASES, "rsens": RSENS_CASES, "capture": CAPTURE_CASES, "key": KEY_CASES}
FIELD_NAMED = {"site", "scenario"}   # a field of a readable file: the field is named, not the file


def format_cases():
    for slot in SLOTS:
        for case_id, make, reason, *only in FORMAT_CASES.get(slot.kind, ()):
            if slot.cases is not None and case_id not in slot.cases or slot.name == "demo":
                continue
            if only and slot.name not in only[0]:
                continue
            yield pytest.param(slot, case_id, make, reason, id=f"{slot.name}-{case_id}")


@pytest.mark.parametrize("slot,case_id,make,reason", list(format_cases()))
def test_bad_content_is_refused(slot, case_id, make, reason, good, tmp_path, capsys):
    bad = tmp_path / f"bad-{slot.name}-{case_id}{slot.suffix or ('.toml' if slot.kind in ('site', 'scenario') else '')}"
    content = make(good)
    if isinstance(content, bytes):
        bad.write_bytes(content)
    else:
        bad.write_text(content)
    rc, out, err = run_cli(slot.argv(bad, good, tmp_path), capsys)
    code = slot.content_code if slot.content_code is not None else slot.code
    structural = case_id.startswith("deep") or case_id in ("list", "magic", "version", "zeros", "text")
    named = bad.name if slot.kind not in FIELD_NAMED or structural else ""
    check(rc, out, err, code, named, reason)


# ---------------------------------------------------------------- the rest


def test_decode_with_the_wrong_key_fails_saying_so(good, tmp_path, capsys):
    """Every frame fails its MAC: not a silent success with 0 frames (exit 1, the reason said)."""
    wrong = tmp_path / "wrong.json"
    site = site_naming(good, tmp_path, **{'key_hex = "00112233445566778899aabbccddeeff"': f'key_hex = "{"ab" * 16}"'})
    assert run_cli(["config", site, "--out", wrong], capsys)[0] == 0
    rc, out, err = run_cli(["decode", good.capture, "--config", wrong], capsys)
    assert rc == 1 and out == "" and "Traceback" not in err
    assert "all 10 frame(s) failed authentication" in err and "key is probably wrong" in err
    rc, out, err = run_cli(["decode", good.capture, "--config", good.node_json], capsys)   # the right key
    assert rc == 0 and len(out.splitlines()) == 10 and "failed authentication" not in err, err


def test_report_refuses_an_sqlite_file_that_is_not_a_ropemon_log(tmp_path, capsys):
    other = tmp_path / "other.db"
    with sqlite3.connect(other) as db:
        db.execute("CREATE TABLE x (a)")
    db.close()
    for argv in (["report", other, "--area-m2", "0.0079"], ["export", other, "--out", tmp_path / "o"]):
        rc, out, err = run_cli(argv, capsys)
        check(rc, out, err, 2, other.name, r"not a ropemon database|not a usable|no schema")
    assert other.stat().st_size > 0


def test_a_fifo_made_after_the_check_cannot_hang_the_open(tmp_path):
    """open_file opens with O_NONBLOCK: even a FIFO swapped in after os.stat does not block."""
    fifo = tmp_path / "late"
    os.mkfifo(fifo)
    orig = files.check_file
    try:
        files.check_file = lambda *a, **k: 0   # the check passed before the swap
        old = signal.signal(signal.SIGALRM, _alarm)
        signal.alarm(5)
        with pytest.raises(files.FileRefused, match="FIFO"):
            files.read_bytes(fifo, "test", 10)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
        files.check_file = orig


def test_evaluate_refuses_a_name_that_is_no_scenario(capsys):
    for name in ("/dev/zero", "no-such-scenario", "/nonexistent/x"):
        rc, out, err = run_cli(["evaluate", name], capsys)
        check(rc, out, err, 2, name, r"no .* and no variant of that name")


def test_the_studies_refuse_a_bad_scenario(tmp_path, capsys):
    deep = tmp_path / "deep.toml"
    deep.write_text(DEEP_TOML_ARRAY)
    rc, out, err = run_cli(["study", "observer-sensitivity", tmp_path / "fifo", "--quick", "--out", tmp_path / "o"],
                           capsys)
    check(rc, out, err, 2, "fifo", r"no variant of that name")
    rc, out, err = run_cli(["study", "seed-spread", deep, "--seeds", "1", "--quick", "--out", tmp_path / "s"], capsys)
    check(rc, out, err, 1, deep.name, r"evaluation failed.*\n.*nested deeper")


def test_the_corpus_is_large_enough():
    n = len(list(generic_cases())) + len(list(format_cases())) + 4
    assert n >= 150, n
