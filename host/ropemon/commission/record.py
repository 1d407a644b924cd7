"""`ropemon record`: arm a cage node to record a commissioning wind, and fetch the recording.

    ropemon record --port PORT --seconds 120          # arm: the node records after its next boot
    ropemon record --port PORT --fetch --out wind.rsens

Arming writes the seconds into the node's flag file (`ropenode.rsens.RECORD_FLAG`);
at its next boot the node removes the flag and, while it monitors as usual,
writes the raw sample records of those seconds to `ropenode.rsens.RECORD_FILE`
(docs/commissioning.md, "Hydraulic compliance"). Fetching copies that file off
with mpremote and checks it is a whole .rsens stream. Both go through the same
pinned mpremote as `ropemon deploy` (`deploy.Mpremote`).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from ropemon.commission.deploy import _NODE_LIB, DeployError, Mpremote
from ropemon.firmware import node_module

_ARM = _NODE_LIB + r"""
with open(FLAG, 'w') as f:
    f.write('%d\n' % SECONDS)
_out({'flag': FLAG, 'seconds': int(open(FLAG).read())})
"""


def arm(mp: Mpremote, seconds: int) -> int:
    """Write the flag; return the seconds the node read back."""
    rs = node_module("rsens")
    if not 0 < seconds <= rs.MAX_SECONDS:
        raise DeployError(f"--seconds: must be 1 .. {rs.MAX_SECONDS}, got {seconds}")
    r = mp.exec(_ARM.replace("FLAG", repr(rs.RECORD_FLAG)).replace("SECONDS", str(seconds)),
                "arming the recording")
    assert isinstance(r, dict)
    return int(r["seconds"])


def fetch(mp: Mpremote, out: Path) -> tuple[int, int, int]:
    """Copy the node's recording to `out`; return (ropes, sample_hz, samples)."""
    from ropemon.commission.reference import RSENS_HEADER, read_rsens

    rs = node_module("rsens")
    with tempfile.TemporaryDirectory(prefix="ropemon-record-") as tmp:
        part = Path(tmp) / rs.RECORD_FILE
        mp.run(["cp", f":{rs.RECORD_FILE}", str(part)], f"copying {rs.RECORD_FILE} off the node",
               extra_s=900.0)  # up to 5.8 MB through the REPL
        try:
            ropes, hz, recs = read_rsens(part)
        except ValueError as e:
            raise DeployError(f"{rs.RECORD_FILE} from the node: {e}") from None
        words = 2 * ropes + 4
        if (part.stat().st_size - RSENS_HEADER.size) % (2 * words):
            raise DeployError(f"{rs.RECORD_FILE} from the node ends within a record: "
                              "the node may still be recording (fetch again when it is done)")
        out.write_bytes(part.read_bytes())
    return ropes, hz, len(recs)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="serial port of the node (e.g. /dev/ttyUSB0, COM3, a virtual node's pty)")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--seconds", type=int, help="arm: record this many seconds (1 .. 600) after the next boot")
    what.add_argument("--fetch", action="store_true", help="copy the recording off the node (with --out)")
    p.add_argument("--out", type=Path, help="with --fetch: the .rsens file to write")
    p.add_argument("--resume", action="store_true",
                   help="do not soft-reset the node before the mpremote step (mpremote's `resume`)")
    p.add_argument("--timeout", type=float, default=20.0, help="seconds to wait for the mpremote step")


def run(args: argparse.Namespace) -> int:
    mp = Mpremote(args.port, args.resume, args.timeout)
    try:
        if args.fetch:
            if args.out is None:
                raise DeployError("--fetch needs --out FILE.rsens")
            ropes, hz, n = fetch(mp, args.out)
            print(f"{args.out}: {n} samples ({n / hz:.1f} s) of {ropes} ropes at {hz} Hz; "
                  f"next: ropemon fit-compliance node.json {args.out} --out compliance.json")
        else:
            s = arm(mp, args.seconds)
            print(f"armed: the node records the first {s} s after its next boot (reset or power it "
                  "when the cage is ready for the wind), then: ropemon record --port "
                  f"{args.port} --fetch --out wind.rsens")
    except DeployError as e:
        print(f"ropemon record: {e}", file=sys.stderr)
        return 1
    return 0
