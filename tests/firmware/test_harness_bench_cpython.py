"""`ropemon bench firmware` runs end to end and reports every figure the docs quote.

Behaviour only (keys, types, units that must agree); the speed and memory
figures themselves are for docs/benchmarks.md, not asserted here.
"""
from __future__ import annotations

import json
import subprocess
import sys

from ropemon.lab.bench import firmware


def test_cli_json_reports_every_figure():
    r = subprocess.run([sys.executable, "-m", "ropemon.cli", "bench", "firmware", "--json", "--quick"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    f = json.loads(r.stdout)
    for key in ("us_per_sample", "allocs_per_sample", "float_baseline_us_per_sample", "heap_bytes",
                "float_ratio", "alloc_bytes_per_sample", "transient_alloc_bytes_per_sample", "us_per_frame",
                "frame_alloc_bytes"):
        assert isinstance(f[key], (int, float)) and f[key] >= 0, key
    assert set(f["mpy_bytes"]) == set(firmware.ARCHS)
    assert all(isinstance(n, int) and n > 1000 for n in f["mpy_bytes"].values())
    assert len(f["us_per_sample_runs"]) == f["repeats"]
    assert f["us_per_sample"] == sorted(f["us_per_sample_runs"])[f["repeats"] // 2]
    assert f["float_ratio"] == f["float_baseline_us_per_sample"] / f["us_per_sample"]
    assert 0 < f["frame_wire_bytes"] <= f["max_wire_len"] == 76
    assert f["crc32_allocates"] == 0 and f["crc32_transient_bytes"] == 0
    assert 0 < f["crc32_us_per_frame"] and 0 < f["crc16_us_same_bytes"] and f["crc32_bytes"] == 69
    for key in ("us_per_sample", "allocs_per_sample", "alloc_bytes_per_sample", "transient_alloc_bytes_per_sample"):
        assert isinstance(f["compliance"][key], (int, float)) and f["compliance"][key] >= 0, key
    text = firmware.describe(f)
    assert "us per sample" in text and "armv6m" in text
