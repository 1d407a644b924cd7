"""`ropemon export DB --out DIR`: a ropemon database as CSV files (frames, events, link_stats, trips).

frames.csv gets a last column `node_time_ms`: each frame's `time_ms` unwrapped per node
(`ropemon.station.nodetime`), a time axis that keeps counting where the node's u32 time wraps.
"""
from __future__ import annotations

import argparse
import csv
import os
import sys
from pathlib import Path

from ropemon.station import files
from ropemon.station.nodetime import NodeClock
from ropemon.station.store import Store, StoreError

NODE_TIME_COL = "node_time_ms"


def add_node_time(frames_csv: str | Path) -> None:
    """Append `node_time_ms` to an exported frames.csv (rows in arrival order, `Store.export_csv`),
    rewriting it through a temporary file beside it."""
    path = Path(frames_csv)
    tmp = path.with_name(path.name + ".tmp")
    clock = NodeClock()
    with path.open(newline="") as fin, tmp.open("w", newline="") as fout:
        r, w = csv.reader(fin), csv.writer(fout)
        head = next(r)
        node, seq, tms = (head.index(c) for c in ("node", "seq", "time_ms"))
        w.writerow(head + [NODE_TIME_COL])
        for row in r:
            w.writerow(row + [clock.ms_of(int(row[node]), int(row[seq]), int(row[tms]))])
    os.replace(tmp, path)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("db", help="ropemon SQLite database")
    p.add_argument("--out", required=True, help="directory for the CSV files (created if missing)")


def run(args: argparse.Namespace) -> int:
    if not Path(args.db).exists():
        print(f"ropemon export: {args.db}: no such database file", file=sys.stderr)
        return 2
    try:  # a regular file that is an SQLite database (ropemon.station.files)
        files.check_sqlite(args.db)
    except files.FileRefused as e:
        print(f"ropemon export: {e}", file=sys.stderr)
        return 2
    try:
        with Store(args.db, readonly=True) as store:
            paths = store.export_csv(args.out)
        for p in paths:
            if p.name == "frames.csv":
                add_node_time(p)
    except (StoreError, OSError) as e:
        print(f"ropemon export: {e}", file=sys.stderr)
        return 2
    for p in paths:
        print(p)
    return 0
