"""`ropemon export DB --out DIR`: a ropemon database as CSV files (frames, events, link_stats, trips)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ropemon.station import files
from ropemon.station.store import Store, StoreError


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
    except (StoreError, OSError) as e:
        print(f"ropemon export: {e}", file=sys.stderr)
        return 2
    for p in paths:
        print(p)
    return 0
