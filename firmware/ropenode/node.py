"""The cage node: samples in, compensated and decimated frames out.

    node = Node(cfg, seq=FrameSeq(path))  # cfg from config.parse; None or a ConfigError = config fault
    ready = node.sample(rec)    # rec: array('H') of 2N+4 words (docs/data-formats.md)
    n = node.frame_into(buf)    # after ready: 0x00 + COBS frame + 0x00 into bytearray(layout.MAX_WIRE_LEN)

The per-sample work is one call of `kernel.step` over two int arrays (config
`P`, state `S`; offsets in kernel.py), closing frame windows too: the viper
build (kernel_viper) where the port has a native emitter, else the plain one.
`sample` never allocates (tests/firmware/test_alloc.py), and it and `frame_into`
keep every int within +-2**30 (tests/firmware/test_int32_ast_cpython.py).
Without a valid config the node does not compensate: every window it offers a
KIND_STATUS frame with ST_CONFIG_FAULT, as node `fallback_id` with its MAC
keyed by `fallback_key`: the refused file's own identity where it is readable
(config.load_for_boot), so a host holding the node's key accepts the frames;
node 255 unkeyed by default.
Frame sequence numbers come from a `bootseq.FrameSeq` (monotonic across resets
when the HAL gives it a boot-counter file; boot 0 without one).
"""
import sys

from micropython import const

from ropenode import layout
from ropenode.bootseq import FrameSeq
from ropenode.frame import FrameWriter

if sys.implementation.name == "micropython":
    try:
        from ropenode import kernel_viper as K
    except Exception:  # no native emitter (e.g. the WebAssembly port): plain bytecode
        from ropenode import kernel as K
else:
    from ropenode import kernel as K

_DEFAULT_WINDOW = const(20)   # 200 Hz / 10 Hz, used when there is no config
_DEFAULT_SAMPLE_HZ = const(200)


class Node:
    def __init__(self, cfg, fallback_id=255, fallback_key=b"", step=None, seq=None):
        """`step` replaces the kernel function (tests compare the viper and plain kernels);
        `seq` is the FrameSeq of this boot (default: boot 0, not persisted)."""
        self.sticky_status = 0    # set by the HAL, e.g. ST_WATCHDOG_RESET
        self.pending_status = 0   # set by the HAL, cleared by the next frame (ST_OVERRUN)
        self.frame_seq = seq if seq is not None else FrameSeq()
        self.ready = False
        self.in_window = 0        # config-fault mode only (the kernel counts otherwise)
        self.sec = 0
        self.sub = 0
        if cfg is None or isinstance(cfg, Exception) or not hasattr(cfg, "ropes"):
            self.config_error = cfg if isinstance(cfg, Exception) else None
            self.n = 0
            self.window_len = _DEFAULT_WINDOW
            self.sample_hz = _DEFAULT_SAMPLE_HZ
            self.writer = FrameWriter(fallback_id, fallback_key)
            self.S = None
            return
        self.config_error = None
        self.n = cfg.ropes
        self.words = 2 * cfg.ropes + 4
        self.window_len = cfg.window
        self.sample_hz = cfg.sample_hz
        self.writer = FrameWriter(cfg.node_id, cfg.key)
        self.P = K.pack(cfg)
        self.S = K.state(cfg)
        self.step = step or K.step
        self.follows_noise = cfg.noise_ref_q6 != 0

    @property
    def temp_cc(self):
        """Oil temperature of the last sample (centi-degC), or OIL_TEMP_ABSENT."""
        return layout.OIL_TEMP_ABSENT if self.S is None else self.S[K.TEMP_CC]

    def rope(self, what):
        """Per-rope values of the last sample, e.g. rope(kernel.TENSION_N), as a list (tests, tools)."""
        return list(self.S[what:what + self.n])

    def sample(self, rec):
        """Process one record; True when a frame window just closed."""
        S = self.S
        if S is None:
            s = self.sub + 1
            if s >= self.sample_hz:
                s = 0
                self.sec += 1
            self.sub = s
            self.in_window += 1
            if self.in_window < self.window_len:
                return False
            self.in_window = 0
        elif len(rec) != self.words:  # the viper kernel reads rec unchecked: refuse a wrong length
            raise ValueError("record of %d words, the config needs %d" % (len(rec), self.words))
        elif not self.step(S, self.P, rec, self.n):
            return False
        self.ready = True
        return True

    def _time_ms(self):
        """Node time (ms, modulo 2**32) at the end of the latched window, as its 16-bit
        halves (low, high): sec * 1000 passes 2**30 after 12 days, so the product is
        formed from the 16-bit halves of sec (every int stays below 2**27)."""
        if self.S is None:
            sec, sub = self.sec, self.sub
        else:
            sec, sub = self.S[K.OUT_SEC], self.S[K.OUT_SUB]
        low = (sec & 0xFFFF) * 1000 + sub * 1000 // self.sample_hz  # < 65536000 + 1000
        return low & 0xFFFF, ((sec >> 16) * 1000 + (low >> 16)) & 0xFFFF

    def frame_into(self, buf):
        """Write the latest window's frame (0x00 + COBS + 0x00) into buf; return its length.

        Runs once per frame (it may allocate: struct packing and SHA-256).
        """
        wr = self.writer
        status = self.sticky_status | self.pending_status
        self.pending_status = 0
        if self.S is None:
            n = wr.pack(layout.KIND_STATUS, 0, self.frame_seq.next(), self._time_ms(),
                        status | layout.ST_CONFIG_FAULT, None, 0, 0, 0, layout.OIL_TEMP_ABSENT)
        else:
            S = self.S
            o = K.OUT_ROPES
            ropes = [(S[o + 4 * i], S[o + 4 * i + 1], S[o + 4 * i + 2], S[o + 4 * i + 3], S[K.OUT_POS + i])
                     for i in range(self.n)]
            stroke = S[K.OUT_STROKE]
            f = S[K.OUT_FAULTS]
            flags = S[K.OUT_FLAGS]
            t = S[K.OUT_TEMP_CC]
            if f & 0x0F:
                status |= layout.ST_PRESSURE_FAULT
            if f & 0xF0:
                status |= layout.ST_DISPLACEMENT_FAULT
            if flags & K.FLAG_IMBALANCE:
                status |= layout.ST_IMBALANCE
            if flags & K.FLAG_BATTERY_LOW:
                status |= layout.ST_BATTERY_LOW
            if flags & K.FLAG_SPEED_FAULT:
                status |= layout.ST_SPEED_FAULT
            if t == layout.OIL_TEMP_ABSENT:
                status |= layout.ST_TEMP_ABSENT
            if stroke:
                status |= layout.ST_STROKE_LIMIT
            status |= (S[K.OUT_HELD] & 0x0F) << layout.ST_HELD_BACK_SHIFT
            r = S[K.NOISE_Q10] - 1024
            if self.follows_noise and (r > layout.NOISE_TOL_Q10 or r < -layout.NOISE_TOL_Q10):
                status |= layout.ST_NOISE_CHANGED
            n = wr.pack(layout.KIND_DATA, f, self.frame_seq.next(), self._time_ms(), status, ropes, S[K.OUT_DEPTH_MM],
                        S[K.OUT_SPEED], S[K.OUT_BATT_MV], t, stroke)
        self.ready = False
        return wr.seal_into(n, buf)

