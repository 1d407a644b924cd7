"""`ropemon decode FILE|-`: frames of a capture (raw receiver bytes) as JSON lines.

One JSON object per good frame on stdout (Frame.to_dict: node, seq and every
payload field, with each rope's pos_01mm and the stroke_mask; frames of layout versions
2 and 3 alike, docs/data-formats.md); the decoder counts on stderr. Exit 0 when frames were decoded; 1 when
the input was read but no frame was decoded (every frame failed its MAC: the key is
probably wrong; or no frame at all), the reason on stderr; 2 when the input cannot be
read (not a regular file, larger than files.MAX_CAPTURE) or a key or node.json is invalid.
Keys: --key-file NODE:PATH and --config node.json, both repeatable, and ROPEMON_KEY_<NODE>=HEX
in the environment, merged (protocol.keys_from_options, as `ropemon monitor`); without keys
authenticity is not checked. `--key NODE:HEX` is refused: a key on the command line can be
read by every user of the computer.
--accept-rewound NODE: the operator accepts a node whose boot counter went back
(docs/protocol.md, "Sequence numbers and replay protection").
"""
from __future__ import annotations

import argparse
import json
import os
import sys

from ropemon.station import files
from ropemon.station.decoder import StreamDecoder
from ropemon.station.protocol import KEY_ENV_PREFIX, KEY_ON_COMMAND_LINE, keys_from_options

CHUNK = 1 << 16


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="FILE|-", help="capture file of receiver bytes, or - for stdin")
    add_key_arguments(p)
    p.add_argument("--config", action="append", default=[], metavar="NODE.JSON",
                   help="take the node id and key from a node.json (repeatable)")
    p.add_argument("--accept-rewound", action="append", type=node_id, default=[], metavar="NODE",
                   help="operator decision: NODE's boot counter really went back (flash wiped or replaced); "
                        "take its next authenticated frame as its new baseline (repeatable)")


class _RefuseKey(argparse.Action):
    """`--key NODE:HEX`: refused, saying what to use instead (the key itself is not repeated)."""

    def __call__(self, parser, namespace, values, option_string=None):
        parser.error(f"argument --key: {KEY_ON_COMMAND_LINE}")


def add_key_arguments(p: argparse.ArgumentParser) -> None:
    """--key-file NODE:PATH (repeatable), and --key, which is refused (`ropemon decode`, `ropemon monitor`)."""
    p.add_argument("--key-file", action="append", default=[], metavar="NODE:PATH",
                   help="HMAC key of a node from a file holding it in hex, readable by its owner only "
                        f"(repeat per node; or {KEY_ENV_PREFIX}<NODE>=HEX in the environment); without keys "
                        "authenticity is not checked")
    p.add_argument("--key", action=_RefuseKey, metavar="NODE:HEX",
                   help="refused: a key on the command line is visible to every user; use --key-file")


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
        keys = keys_from_options(args.key_file, args.config, args.accept_rewound)
    except ValueError as e:
        print(f"ropemon decode: {e}", file=sys.stderr)
        return 2
    dec = StreamDecoder(keys or None, accept_rewound=args.accept_rewound)
    out = sys.stdout
    if args.input == "-":
        src = sys.stdin.buffer
        close = False
    else:
        try:  # a regular file only (a FIFO or /dev/zero would never end), at most MAX_CAPTURE
            src = files.open_file(args.input, "capture", files.MAX_CAPTURE)
        except files.FileRefused as e:
            print(f"ropemon decode: {e}", file=sys.stderr)
            return 2
        close = True
    read = 0
    try:
        while True:
            try:
                chunk = src.read(CHUNK)
            except OSError as e:
                print(f"ropemon decode: cannot read {args.input}: {e.strerror or e}", file=sys.stderr)
                return 2
            if not chunk:
                break
            read += len(chunk)
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
    return verdict(dec.counts, read, "stdin" if args.input == "-" else args.input)


def verdict(c, read: int, name: str) -> int:
    """The exit status of a decode whose input was read: 1, with the reason on stderr, when
    no frame was decoded (every frame failed its MAC: the key is probably wrong; or the input
    held no frame); 0 otherwise, with a warning when some frames failed their MAC."""
    if c.mac_fail and not c.frames_ok:
        print(f"ropemon decode: {name}: all {c.mac_fail} frame(s) failed authentication (MAC) and none "
              "passed: the key is probably wrong for the node (check --key-file / --config against the "
              "node.json the node runs)", file=sys.stderr)
        return 1
    if c.mac_fail:
        print(f"ropemon decode: warning: {name}: {c.mac_fail} frame(s) failed authentication (MAC): a wrong "
              "key for one of the nodes, a node without a key, or frames not sent by a node", file=sys.stderr)
    if not c.frames_ok:
        why = "empty input" if not read else f"{read} bytes with no frame this host can decode"
        print(f"ropemon decode: {name}: no frame decoded ({why}): not a capture of ropemon frames?",
              file=sys.stderr)
        return 1
    return 0
