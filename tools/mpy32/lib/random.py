"""random for the mpy32 port (extmod/modrandom.c is not in the source it is built from):
xorshift32 seeded from the clock, as MicroPython's own (getrandbits, randrange, randint,
random, choice, seed)."""
import time

_s = (time.ticks_us() ^ (time.time_ns() & 0x3FFFFFFF)) | 1


def seed(n=None):
    global _s
    _s = ((time.ticks_us() if n is None else n) & 0xFFFFFFFF) or 1


def _next():
    global _s
    x = _s
    x ^= (x << 13) & 0xFFFFFFFF
    x ^= x >> 17
    x ^= (x << 5) & 0xFFFFFFFF
    _s = x
    return x


def getrandbits(k):
    if k < 0 or k > 32:
        raise ValueError("bits must be 0..32")
    return _next() >> (32 - k) if k else 0


def randrange(start, stop=None, step=1):
    if stop is None:
        start, stop = 0, start
    n = (stop - start + step - 1) // step
    if n <= 0:
        raise ValueError("empty range")
    return start + step * (_next() % n)


def randint(a, b):
    return randrange(a, b + 1)


def random():
    return (_next() >> 8) / 16777216.0


def choice(seq):
    return seq[randrange(len(seq))]
