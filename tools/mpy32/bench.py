"""The firmware benchmark (ropemon bench firmware's script) on the 32-bit builds of tools/mpy32.

    .venv/bin/python tools/mpy32/bench.py [--repeats N] [--source] [--builds x64,x86,armv7m]

Runs host/ropemon/lab/bench/firmware.py's on-node script, unchanged, with the node imported
from .mpy files cross-compiled for each build (mpy-cross -march=x86 / armv7m), on the unix
port (x64, for comparison), the i386 build (native) and the Thumb-2 build (emulated by
qemu-user: its times are the emulator's, not a Cortex-M's). With --source, each build also
imports the node from the firmware's .py sources (compiled by the interpreter itself), the
runs alternating with the .mpy ones. Prints a markdown table of medians over N runs
(docs/benchmarks.md, "32-bit builds").

    .venv/bin/python tools/mpy32/bench.py --least-heap [--source] [--builds ...]

instead tries, for each build, every heap size (`-X heapsize`) from 16 to 256 KiB in
1 KiB steps, and prints the least in which a board's boot completes and the least from
which it completes in every size (fragmentation moves with the heap's size, so a boot
that fits in one size can fail in a larger one). What runs: the modules hal_board
imports first, the config loaded, parsed and released as
hal_board._boot does, the Node built, then the board's front end modules (boards,
frontend, ads1115), as a board loads them, and 400 samples and their frames. A measured bound on everything the boot holds
at once, the interpreter's own start included; not hal_board, deployswap and main.py
(hal_board needs `machine`). The 32-bit builds have no C json: their lib/json.py, loaded
from .mpy, is counted too.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import tempfile
from pathlib import Path

from ropemon.commission.nodejson import node_part
from ropemon.firmware import micropython_command, node_module
from ropemon.lab.bench import firmware as fb

ROOT = Path(__file__).resolve().parents[2]
MPY32 = ROOT / ".cache" / "mpy32"
BUILDS = {  # name: (interpreter, mpy-cross -march)
    "unix port, x86-64": (micropython_command(), "x64"),
    "mpy32 i386 (native)": (str(MPY32 / "x86" / "micropython"), "x86"),
    "mpy32 Thumb-2 (qemu-arm)": (str(MPY32 / "thumb" / "micropython-qemu"), "armv7m"),
}


def run_once(exe: str, arch: str, tmp: Path, samples: int, repeats: int, chunk: int,
             source: bool = False) -> dict:
    """One run of the on-node script; the node from .mpy files (or, with source, from the .py files)."""
    fw = fb.FIRMWARE
    tree = tmp / arch
    mpy_bytes = fb.compile_tree(fw, tree, arch)
    config = fw / "node.json"
    on_node = tmp / "node-on-node.json"
    on_node.write_text(json.dumps(node_part(json.loads(config.read_text())), separators=(",", ":")))
    script = tmp / "bench_node.py"
    max_wire = node_module("layout").MAX_WIRE_LEN
    script.write_text(fb.SCRIPT.replace("NODE_JSON", json.dumps(str(on_node)))
                      .replace("PHYS_JSON", json.dumps(str(config)))
                      .replace("SAMPLES", str(samples)).replace("REPEATS", str(repeats))
                      .replace("CHUNK", str(chunk)).replace("MAX_WIRE_LEN", str(max_wire)))
    env = dict(os.environ, MICROPYPATH=str(fw if source else tree))
    r = subprocess.run([exe, "-X", "heapsize=4M", str(script)], cwd=tmp, env=env,
                       capture_output=True, text=True, timeout=1800)
    if r.returncode != 0:
        raise RuntimeError(f"{exe}: {r.stdout}{r.stderr}")
    out = json.loads(r.stdout.strip().splitlines()[-1])
    out["mpy_bytes"] = mpy_bytes
    return out


LEAST_SCRIPT = r'''
import gc, array
from ropenode import layout, rsens
from ropenode.bootseq import FrameSeq


def load_config():
    from ropenode import config
    cfg, node_id, key, reason = config.load_for_boot(NODE_JSON)
    if cfg is None:
        raise SystemExit("refused: %s" % reason)
    config.release()
    return cfg, node_id, key


def boot():
    cfg, node_id, key = load_config()
    gc.collect()
    from ropenode.node import Node
    return Node(cfg, node_id, key)


node = boot()
gc.collect()
from ropenode import boards
from ropenode.frontend import FrontEnd
gc.collect()
rec = array.array("H", RECORD)
buf = bytearray(MAX_WIRE_LEN)
frames = 0
for k in range(400):
    rec[0] = RECORD[0] + (k & 7)
    if node.sample(rec):
        frames += node.frame_into(buf) > 0
print("ok", frames)
'''


def boot_in(exe: str, arch: str, tmp: Path, source: bool = False):
    """A function of a heap size (bytes): whether LEAST_SCRIPT completes in a heap that
    size on this build, the node loaded from .mpy files (or with source, its .py files)."""
    fw = fb.FIRMWARE
    tree = tmp / arch
    fb.compile_tree(fw, tree, arch)
    if arch != "x64":  # the 32-bit builds' json is lib/json.py (a board's is C): from .mpy, as a board's code
        fb.compile_tree(ROOT / "tools" / "mpy32" / "lib", tree, arch)
    config = fw / "node.json"
    doc = json.loads(config.read_text())
    on_node = tmp / "node-on-node.json"
    on_node.write_text(json.dumps(node_part(doc), separators=(",", ":")))
    ph = doc["physical"]
    n = ph["ropes"]
    record = ([(c["counts_4mA"] + c["counts_20mA"]) // 2 for c in ph["pressure_channels"]]
              + [(c["counts_lo"] + c["counts_hi"]) // 2 for c in ph["displacement_channels"]]
              + [60000, 0xFFFF, 0, 0])
    assert len(record) == 2 * n + 4
    script = tmp / "least_heap.py"
    script.write_text(LEAST_SCRIPT.replace("NODE_JSON", json.dumps(str(on_node)))
                      .replace("RECORD", repr(record))
                      .replace("MAX_WIRE_LEN", str(node_module("layout").MAX_WIRE_LEN)))
    env = dict(os.environ, MICROPYPATH=str(fw if source else tree))

    def boots(size: int) -> bool:
        r = subprocess.run([exe, "-X", f"heapsize={size}", str(script)], cwd=tmp, env=env,
                           capture_output=True, text=True, timeout=600)
        return r.returncode == 0 and r.stdout.split()[:1] == ["ok"] and int(r.stdout.split()[1]) > 0

    return boots


def least_heap(exe: str, arch: str, tmp: Path, source: bool = False) -> tuple[int, int]:
    """(the least `-X heapsize` in which LEAST_SCRIPT completes, the least from which it
    completes in every size up to 256 KiB), in bytes on a 1 KiB grid from 16 KiB."""
    boots = boot_in(exe, arch, tmp, source)
    # not monotonic: where the collections fall, and so the fragmentation, moves with the
    # heap's size, so a boot that fits in one size can fail in a larger one
    sizes = range(16 * 1024, 256 * 1024 + 1, 1024)
    ok = [boots(z) for z in sizes]
    if not ok[-1]:
        raise RuntimeError(f"{exe}: the boot fails even with a {sizes[-1]}-byte heap")
    fails = [z for z, good in zip(sizes, ok) if not good]
    return min(z for z, good in zip(sizes, ok) if good), (fails[-1] + 1024 if fails else sizes[0])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5, help="whole runs per build (median)")
    ap.add_argument("--source", action="store_true", help="also import the node from the .py sources")
    ap.add_argument("--least-heap", action="store_true",
                    help="find the least heap each build boots and runs the node in, instead of timing")
    ap.add_argument("--builds", default=",".join(a for _, a in BUILDS.values()),
                    help="the builds to run, by .mpy arch (x64: unix port, x86: i386, armv7m: Thumb-2)")
    a = ap.parse_args()
    wanted = a.builds.split(",")
    loadings = [False, True] if a.source else [False]
    if a.least_heap:
        print("| build | node loaded from | least heap it booted in | booted in every heap from |\n"
              "|---|---|---:|---:|")
        with tempfile.TemporaryDirectory(prefix="ropemon-mpy32-heap-") as t:
            for name, (exe, arch) in BUILDS.items():
                if arch in wanted:
                    for src in loadings:
                        least, every = least_heap(exe, arch, Path(t), source=src)
                        print(f"| {name} | {'source (.py)' if src else '.mpy'} | {least:,} | {every:,} |",
                              flush=True)
        return
    rows = []
    with tempfile.TemporaryDirectory(prefix="ropemon-mpy32-bench-") as t:
        for name, (exe, arch) in BUILDS.items():
            if arch not in wanted:
                continue
            runs = {src: [] for src in loadings}
            for _ in range(a.repeats):  # .mpy and source alternate, run after run
                for src in loadings:
                    runs[src].append(run_once(exe, arch, Path(t), 1000, 5, 20, source=src))
            for src in loadings:
                rs = runs[src]

                def med(key):
                    return statistics.median(r[key] for r in rs)
                rows.append((name, arch, "source (.py)" if src else ".mpy", med("us_per_sample"),
                             med("float_baseline_us_per_sample"), med("allocs_per_sample"), rs[0]["mpy_bytes"],
                             med("heap_bytes"), med("heap_boot_peak_bytes"), med("heap_released_bytes")))
    print(f"median of {a.repeats} runs, each the median of 5 x 50 chunks of 20 samples\n")
    print("| build | .mpy arch | node loaded from | us/sample (fixed) | us/sample (float baseline) "
          "| samples that allocate | .mpy bytes (firmware/) | heap after boot | boot heap peak "
          "| freed by the config release |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, arch, loading, us, fl, al, mpy, heap, peak, rel in rows:
        print(f"| {name} | {arch} | {loading} | {us:.2f} | {fl:.2f} | {al:.3f} | {mpy} | {heap:.0f} | {peak:.0f} "
              f"| {rel:.0f} |")


if __name__ == "__main__":
    main()
