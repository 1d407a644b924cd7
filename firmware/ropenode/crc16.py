"""CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0).

Catalogue name CRC-16/IBM-3740; check value crc16(b"123456789") == 0x29B1.
Same result as CPython's binascii.crc_hqx(data, 0xFFFF). The node config's CRC
(node.json `crc`, ropenode.config); radio frames use CRC-32 (ropenode.crc32).
Table-driven; the table is built once at import.
"""
import array

_TABLE = array.array("H", [0] * 256)


def _build():
    for i in range(256):
        c = i << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x1021) if c & 0x8000 else (c << 1)
        _TABLE[i] = c & 0xFFFF


_build()


def crc16(buf, n=-1, crc=0xFFFF):
    """CRC of the first n bytes of buf (all when n < 0). Allocation-free."""
    t = _TABLE
    if n < 0:
        n = len(buf)
    for i in range(n):
        crc = ((crc << 8) & 0xFF00) ^ t[((crc >> 8) ^ buf[i]) & 0xFF]
    return crc
