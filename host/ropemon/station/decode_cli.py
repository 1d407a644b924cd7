"""`ropemon decode FILE|-`: frames of a capture (raw receiver bytes) as JSON lines.

One JSON object per good frame on stdout (Frame.to_dict: node, seq and every
payload field); the decoder counts on stderr. Exit 0 when the input was read
(even if it held no good frame), 2 when it cannot be read or a key is invalid.
Keys: --key NODE:HEX and --config node.json, both repeatable and merged
(protocol.keys_from_options, as `ropemon monitor`); without keys authenticity is not checked.
--accept-rewound NODE: the operator accepts a node whose boot counter went back
(docs/protocol.md, "Sequence numbers and replay protection").
"""
from __future__ import annotations

import argparse
import json
import os
import sys

from ropemon.station.decoder import StreamDecoder
from ropemon.station.protocol import keys_from_options

CHUNK = 1 << 16


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="FILE|-", help="capture file of receiver bytes, or - for stdin")
    p.add_argument("--key", action="append", default=[], metavar="NODE:HEX",
                   help="HMAC key of a node (repeat per node); without keys authenticity is not checked")
    p.add_argument("--config", action="append", default=[], metavar="NODE.JSON",
                   help="take the node id and key from a node.json (repeatable)")
    p.add_argument("--accept-rewound", action="append", type=node_id, default=[], metavar="NODE",
                   help="operator decision: NODE's boot counter really went back (flash wiped or replaced); "
                        "take its next authenticated frame as its new baseline (repeatable)")


def node_id(text: str) -> int:
    """A node id argument: 0..255."""
    try:
        n = int(text)
    except ValueError:
        n = -1
    if not 0 <= n <= 255:
        raise argparse.ArgumentTypeError(f"{text!r}: a node id is an integer 0..255")
    return n


def run(args: argparse.Namespace) -> int:
    try:
        keys = keys_from_options(args.key, args.config, args.accept_rewound)
    except ValueError as e:
        print(f"ropemon decode: {e}", file=sys.stderr)
        return 2
    dec = StreamDecoder(keys or None, accept_rewound=args.accept_rewound)
    out = sys.stdout
    try:
        if args.input == "-":
            src = sys.stdin.buffer
            close = False
        else:
            src = open(args.input, "rb")
            close = True
    except OSError as e:
        print(f"ropemon decode: cannot read {args.input}: {e.strerror or e}", file=sys.stderr)
        return 2
    try:
        while True:
            try:
                chunk = src.read(CHUNK)
            except OSError as e:
                print(f"ropemon decode: cannot read {args.input}: {e.strerror or e}", file=sys.stderr)
                return 2
            if not chunk:
                break
            lines = [json.dumps(f.to_dict(), separators=(",", ":")) for f in dec.feed(chunk)]
            if lines:
                out.write("\n".join(lines) + "\n")
        out.flush()
    except BrokenPipeError:
        # The reader (e.g. `head`) went away: not an input error.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    finally:
        if close:
            src.close()
    dec.finish()
    print(f"ropemon decode: {dec.summary()}", file=sys.stderr)
    return 0
