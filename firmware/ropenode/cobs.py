"""COBS encoding into a caller's buffer (Cheshire & Baker 1999), allocation-free.

The host decodes with the `cobs` package; this is the node's half.
"""


def encode_into(src, n, dst, start=0):
    """COBS-encode src[:n] into dst from index `start`, append the 0x00 delimiter;
    return the index after it (bytes written when start is 0).

    dst must hold start + n + n // 254 + 2 bytes.
    """
    code_at = start
    code = 1
    o = start + 1
    for i in range(n):
        b = src[i]
        if b == 0:
            dst[code_at] = code
            code_at = o
            o += 1
            code = 1
        else:
            dst[o] = b
            o += 1
            code += 1
            if code == 0xFF:
                dst[code_at] = code
                code_at = o
                o += 1
                code = 1
    dst[code_at] = code
    dst[o] = 0
    return o + 1
