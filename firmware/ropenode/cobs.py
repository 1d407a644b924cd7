"""COBS encoding into a caller's buffer (Cheshire & Baker 1999), allocation-free.

The host decodes with the `cobs` package; this is the node's half.
"""


def encode_into(src, n, dst):
    """COBS-encode src[:n] into dst, append the 0x00 delimiter; return bytes written.

    dst must hold n + n // 254 + 2 bytes.
    """
    code_at = 0
    code = 1
    o = 1
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
