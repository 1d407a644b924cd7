"""CRC-32 (IEEE 802.3; catalogue name CRC-32/ISO-HDLC) in 16-bit halves, for the frame.

Reflected poly 0xEDB88320, init 0xFFFFFFFF, xorout 0xFFFFFFFF; check value
crc32(b"123456789") == 0xCBF43926. Same result as CPython's binascii.crc32 /
zlib.crc32, which the host uses.

A 32-bit value is not a small int on a 32-bit MicroPython (those end at
+-2**30), so the register is kept as two 16-bit halves `hi` and `lo`, and the
256-entry table as two array('H') of its halves (1 KiB, built once at import).
Every int stays below 2**16: allocation-free. This module is the reference on
the node: some ports have binascii.crc32, not all; tests check it against
binascii.crc32 under CPython and, where present, under MicroPython.
"""
import array

_HI = array.array("H", bytes(512))
_LO = array.array("H", bytes(512))


def _build():
    for i in range(256):
        hi, lo = 0, i
        for _ in range(8):
            low_bit = lo & 1
            lo = (lo >> 1) | ((hi & 1) << 15)
            hi >>= 1
            if low_bit:
                hi ^= 0xEDB8
                lo ^= 0x8320
        _HI[i] = hi
        _LO[i] = lo


_build()


def crc32_into(buf, n):
    """Write the CRC-32 of buf[:n] little-endian into buf[n:n + 4]; return n + 4.

    Allocation-free, every int below 2**16 (the 32-bit value is never formed).
    A while loop, not `for k in range(n)`: it keeps the call frame at 11 words,
    on the C stack (tools/check_frame_spill.py), and is as fast.
    """
    th = _HI
    tl = _LO
    hi = 0xFFFF
    lo = 0xFFFF
    k = 0
    while k < n:
        i = (lo ^ buf[k]) & 0xFF
        lo = ((lo >> 8) | ((hi & 0xFF) << 8)) ^ tl[i]
        hi = (hi >> 8) ^ th[i]
        k += 1
    lo ^= 0xFFFF
    hi ^= 0xFFFF
    buf[k] = lo & 0xFF
    k += 1
    buf[k] = lo >> 8
    k += 1
    buf[k] = hi & 0xFF
    k += 1
    buf[k] = hi >> 8
    return k + 1
