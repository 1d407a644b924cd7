"""Helpers for the firmware tests that run under both CPython and MicroPython (not a test file)."""
import json
import sys


def find_file(rel):
    """Open-able path of a repo file: tries the firmware/ and tests dirs on sys.path, then cwd."""
    here = __file__.rsplit("/", 1)[0] if "/" in __file__ else "."
    cands = [here + "/../../" + rel, rel]
    for d in sys.path:
        cands.append((d or ".") + "/../" + rel)
    for c in cands:
        try:
            open(c).close()
            return c
        except OSError:
            pass
    raise OSError("not found: " + rel)


def load_json(rel):
    with open(find_file(rel)) as f:
        return json.load(f)


def node_doc():
    """The shipped firmware/node.json as a dict."""
    return load_json("firmware/node.json")


def cobs_decode(data):
    """Plain COBS decoder for tests (data without the 0x00 delimiter)."""
    out = bytearray()
    i = 0
    while i < len(data):
        code = data[i]
        if code == 0:
            raise ValueError("zero byte inside COBS data")
        out += data[i + 1:i + code]
        i += code
        if code < 0xFF and i < len(data):
            out.append(0)
    return bytes(out)


def frame_raw(wire, n):
    """The raw frame of the first n bytes of a node's wire buffer (0x00 + COBS + 0x00),
    its delimiters and its CRC-32 checked (the node's own crc32_into recomputes it)."""
    from ropenode.crc32 import crc32_into
    assert n >= 3 and wire[0] == 0 and wire[n - 1] == 0, (n, bytes(wire[:n]))
    for i in range(1, n - 1):
        assert wire[i] != 0, i
    raw = cobs_decode(bytes(wire[1:n - 1]))
    again = bytearray(raw)
    crc32_into(again, len(raw) - 4)
    assert bytes(again) == raw, "CRC-32 mismatch"
    return raw


def unhex(s):
    import binascii
    return binascii.unhexlify(s)
