"""The node's start depth comes from SITE.toml ([hoist] start_depth_m), never from the
simulator's truth: a site without it is refused, and a node started where the site says
reports the cage's depth from there (the firmware under CPython)."""
from __future__ import annotations

import array
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ropemon.firmware import node_module
from ropemon.commission.nodejson import make_node_json
from ropemon.commission.site import SiteError, load_site, physical_from_site

ROOT = Path(__file__).resolve().parents[2]
SCEN = ROOT / "scenarios"
HZ = 200


@pytest.fixture
def site_dir(tmp_path) -> Path:
    for name in ("paper-site.toml", "paper-friction.json", "paper-compliance.json"):
        shutil.copy(SCEN / name, tmp_path / name)
    return tmp_path


def set_start(site_dir: Path, line: str | None) -> Path:
    site = site_dir / "paper-site.toml"
    text = (SCEN / "paper-site.toml").read_text()
    old = next(ln for ln in text.splitlines() if ln.startswith("start_depth_m"))
    site.write_text(text.replace(old + "\n", "" if line is None else line + "\n"))
    return site


def test_the_site_must_say_where_the_node_starts(site_dir):
    with pytest.raises(SiteError, match=r"^hoist.start_depth_m: missing \(the depth in m of the landing"):
        load_site(set_start(site_dir, None))
    with pytest.raises(SiteError, match=r"^hoist.start_depth_m: must be <= 810"):
        load_site(set_start(site_dir, "start_depth_m = 900.0"))


def wind_up(ph: dict, start_m: float, up_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Records of the cage at rest at start_m for 2 s, then winding up `up_m` at 4 m/s and
    resting 2 s; healthy rope channels, the counter and the Hall pair as docs/data-formats.md.
    Returns (records, true depth)."""
    n = ph["ropes"]
    v = 4.0
    t_move = up_m / v
    t = np.arange(int((4 + t_move) * HZ)) / HZ
    depth = start_m - np.clip(t - 2.0, 0, t_move) * v
    rec = np.zeros((t.size, 2 * n + 4), dtype=np.uint16)
    for i in range(n):
        pc, dc = ph["pressure_channels"][i], ph["displacement_channels"][i]
        rec[:, i] = (pc["counts_4mA"] + pc["counts_20mA"]) // 2
        rec[:, n + i] = (dc["counts_lo"] + dc["counts_hi"]) // 2
    rec[:, 2 * n] = 16000
    pulses = np.floor((depth - start_m) / ph["speed_m_per_pulse"] + 1e-9).astype(np.int64)
    rec[:, 2 * n + 2] = (pulses + 30000) % 65536
    marks = np.asarray(ph["hall_marks_m"])
    a = (np.abs(depth[:, None] - marks[None, :]) <= 0.05).any(axis=1)
    b = (np.abs(depth[:, None] - 0.2 - marks[None, :]) <= 0.05).any(axis=1)
    rec[:, 2 * n + 3] = a.astype(np.uint16) | (b.astype(np.uint16) << 1)
    return rec, depth


@pytest.mark.parametrize("start", [808.0, 405.0])
def test_a_node_started_where_the_site_says_reports_the_cages_depth(site_dir, start):
    site = load_site(set_start(site_dir, f"start_depth_m = {start}"))
    assert site.hoist.start_depth_m == start
    doc = make_node_json(physical_from_site(site))
    assert doc["physical"]["start_depth_m"] == start
    assert doc["node"]["shaft"]["start_depth_mm"] == round(start * 1000)
    node = node_module("node").Node(node_module("config").parse(doc))
    kernel = node_module("kernel")
    rec, depth = wind_up(doc["physical"], start, 30.0)
    seen = []
    for k, row in enumerate(rec):
        node.sample(array.array("H", row.tolist()))
        if k % 100 == 99:
            seen.append((node.S[kernel.DEPTH_MM] / 1000.0, depth[k]))
    assert seen[0][0] == pytest.approx(start, abs=0.02)
    assert max(abs(got - want) for got, want in seen) < 0.05
    assert seen[-1][0] == pytest.approx(start - 30.0, abs=0.05)


def test_the_simulators_node_json_takes_the_sites_start_depth_not_the_cages(tmp_path):
    # short-test starts its cage at the pithead (2 m); the site starts its node at 808 m
    out = tmp_path / "sim"
    subprocess.run([sys.executable, "-m", "ropemon.cli", "simulate", str(SCEN / "short-test.toml"),
                    "--out", str(out)], check=True, capture_output=True)
    doc = json.loads((out / "node.json").read_text())
    truth = np.load(out / "truth.npz")
    site = load_site(SCEN / "paper-site.toml")
    assert doc["physical"]["start_depth_m"] == site.hoist.start_depth_m
    assert abs(truth["cage_depth_m"][0] - site.hoist.start_depth_m) > 100
