#!/usr/bin/env python3
"""Run a virtual cage node (MicroPython unix port on a pty) until Ctrl-C.

    .venv/bin/python tools/virtual_node.py [--root DIR]

prints the port; then, in another shell:

    .venv/bin/mpremote connect PORT exec "import sys; print(sys.platform)"
    .venv/bin/ropemon deploy --port PORT --config node.json

The node's filesystem is DIR (a new temporary directory by default). A soft
reset restarts the interpreter, as on a board; `mpremote connect PORT resume ...`
keeps its state between runs.
"""
from __future__ import annotations

import argparse
import signal
import sys
import tempfile
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "host"))

from ropemon.lab.virtualnode import VirtualNode  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", type=Path, help="the node's filesystem (default: a new temporary directory)")
    args = p.parse_args()
    root = args.root or Path(tempfile.mkdtemp(prefix="ropemon-node-"))
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    with VirtualNode(root) as node:
        print(f"virtual node: port {node.port}, filesystem {root}", flush=True)
        print(f"  ropemon deploy --port {node.port} --config node.json", flush=True)
        try:
            while node.running() and not done.wait(0.5):
                pass
        except KeyboardInterrupt:
            pass
        if not node.running():
            print("virtual node: the micropython process ended", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
