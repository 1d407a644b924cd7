"""The cage node: samples in, compensated and decimated frames out.

    node = Node(cfg)            # cfg from config.parse; None or a ConfigError = config fault
    ready = node.sample(rec)    # rec: array('H') of 2N+4 words (docs/data-formats.md)
    n = node.frame_into(buf)    # after ready: COBS frame + 0x00 into bytearray(64)

`sample` never allocates (proved under micropython.heap_lock by
tests/firmware/test_alloc.py) and keeps every int within +-2**30.
Without a valid config the node does not compensate: every window it offers a
KIND_STATUS frame with ST_CONFIG_FAULT (node id `fallback_id`, MAC keyed with
`fallback_key`, empty by default).
"""
import array

from micropython import const

from ropenode import layout
from ropenode.compensate import Compensator
from ropenode.decimate import Window
from ropenode.layout import OIL_TEMP_ABSENT as _TEMP_ABSENT
from ropenode.frame import FrameWriter
from ropenode.shaft import Shaft

DEFAULT_WINDOW = const(20)   # 200 Hz / 10 Hz, used when there is no config
DEFAULT_SAMPLE_HZ = const(200)


class Node:
    def __init__(self, cfg, fallback_id=255, fallback_key=b""):
        if cfg is None or isinstance(cfg, Exception) or not hasattr(cfg, "ropes"):
            self.cfg = None
            self.config_error = cfg if isinstance(cfg, Exception) else None
            self.n = 0
            self.window_len = DEFAULT_WINDOW
            self.sample_hz = DEFAULT_SAMPLE_HZ
            self.writer = FrameWriter(fallback_id, fallback_key)
            self.comp = None
        else:
            self.cfg = cfg
            self.config_error = None
            n = self.n = cfg.ropes
            self.window_len = cfg.window
            self.sample_hz = cfg.sample_hz
            self.frame_hz = cfg.frame_hz
            self.writer = FrameWriter(cfg.node_id, cfg.key)
            self.comp = Compensator(cfg)
            self.assumed_cc = cfg.oil_temp_assumed_cc
            self.shaft = Shaft(cfg)
            self.win = Window(n)
            # the closed window, as it goes into the next frame
            self.out_ropes = array.array("i", [0] * (4 * n))
        self.in_window = 0
        self.sec = 0          # node time: whole seconds + samples into the second
        self.sub = 0
        self.seq = 0
        self.sticky_status = 0    # set by the HAL, e.g. ST_WATCHDOG_RESET
        self.pending_status = 0   # set by the HAL, cleared by the next frame (ST_OVERRUN)
        self.temp_cc = layout.OIL_TEMP_ABSENT
        self.out_status = 0
        self.out_faults = 0
        self.out_speed = 0
        self.out_batt_mv = 0
        self.out_temp_cc = layout.OIL_TEMP_ABSENT
        self.out_sec = 0
        self.out_sub = 0
        self.out_depth_mm = 0
        self.ready = False

    def _tick(self):
        s = self.sub + 1
        if s >= self.sample_hz:
            s = 0
            self.sec += 1
        self.sub = s
        self.in_window += 1
        if self.in_window >= self.window_len:
            self.in_window = 0
            return True
        return False

    def _temperature(self, c):
        """Oil temperature in centi-degC, or OIL_TEMP_ABSENT (assumed value used)."""
        cfg = self.cfg
        if not cfg.temp_fitted or c == 0xFFFF or c < cfg.temp_fault_lo or c > cfg.temp_fault_hi:
            return _TEMP_ABSENT
        return ((c - cfg.temp_counts_at_0c) * cfg.temp_cc_mul) >> cfg.temp_cc_shift

    def sample(self, rec):
        """Process one record; True when a frame window just closed."""
        comp = self.comp
        if comp is None:
            if self._tick():
                self.ready = True
                return True
            return False
        b = self.n << 1
        t = self._temperature(rec[b + 1])
        self.temp_cc = t
        good = comp.step(rec, self.assumed_cc if t == _TEMP_ABSENT else t)
        w = self.win
        w.add(comp.tension_n, comp.p_kpa, good)
        w.faults |= comp.fault_mask
        w.batt_sum += rec[b]
        self.shaft.update(rec[b + 2], rec[b + 3])
        if self._tick():
            self._close()
            self.ready = True
            return True
        return False

    def _close(self):
        """Latch the window's figures for the next frame; start a new window."""
        cfg = self.cfg
        w = self.win
        o = self.out_ropes
        st = 0
        tot = 0
        used = 0
        for i in range(self.n):
            c = w.count[i]
            b = 4 * i
            if c == 0:
                o[b] = o[b + 1] = o[b + 2] = layout.TENSION_ABSENT
                o[b + 3] = layout.RAW_KPA_ABSENT
                continue
            o[b] = _dan((w.sum_n[i] + 5 * c) // (10 * c))
            o[b + 1] = _dan((w.min_n[i] + 5) // 10)
            o[b + 2] = _dan((w.max_n[i] + 5) // 10)
            p = (w.sum_kpa[i] + (c >> 1)) // c
            o[b + 3] = 0 if p < 0 else (65534 if p > 65534 else p)
            tot += o[b]
            used += 1
        if used > 1 and tot > 0:
            lim = cfg.imbalance_permille
            for i in range(self.n):
                m = o[4 * i]
                if m != layout.TENSION_ABSENT:
                    d = m * used - tot
                    if d < 0:
                        d = -d
                    # |m - mean| / mean > lim / 1000, in integers (<= 2**17 * 1000)
                    if d * 1000 > lim * tot:
                        st |= layout.ST_IMBALANCE
        f = w.faults
        if f & 0x0F:
            st |= layout.ST_PRESSURE_FAULT
        if f & 0xF0:
            st |= layout.ST_DISPLACEMENT_FAULT
        bs = cfg.battery_mv_shift
        bm = ((w.batt_sum // self.window_len) * cfg.battery_mv_mul + (1 << bs >> 1)) >> bs
        self.out_batt_mv = bm if bm < 65535 else 65535
        if bm < cfg.battery_low_mv:
            st |= layout.ST_BATTERY_LOW
        if self.temp_cc == layout.OIL_TEMP_ABSENT:
            st |= layout.ST_TEMP_ABSENT
        sh = self.shaft
        if sh.fault:
            st |= layout.ST_SPEED_FAULT
            sh.fault = False
        self.out_speed = sh.close_window(self.frame_hz)
        self.out_depth_mm = sh.depth_mm
        self.out_temp_cc = self.temp_cc
        self.out_sec = self.sec
        self.out_sub = self.sub
        self.out_status = st
        self.out_faults = f
        w.reset()

    def _time_ms(self):
        """Node time (ms, modulo 2**32) at the end of the latched window."""
        if self.comp is None:
            sec, sub = self.sec, self.sub
        else:
            sec, sub = self.out_sec, self.out_sub
        return (sec * 1000 + sub * 1000 // self.sample_hz) & 0xFFFFFFFF

    def frame_into(self, buf):
        """Write the latest window's frame (COBS + 0x00) into buf; return its length.

        Runs once per frame (it may allocate: struct packing and SHA-256).
        """
        wr = self.writer
        status = self.sticky_status | self.pending_status
        self.pending_status = 0
        if self.comp is None:
            n = wr.pack(layout.KIND_STATUS, 0, self.seq, self._time_ms(),
                        status | layout.ST_CONFIG_FAULT, None, 0, 0, 0, layout.OIL_TEMP_ABSENT)
        else:
            o = self.out_ropes
            ropes = [(o[4 * i], o[4 * i + 1], o[4 * i + 2], o[4 * i + 3]) for i in range(self.n)]
            d = self.out_depth_mm
            d = -0x80000000 if d < -0x80000000 else (0x7FFFFFFF if d > 0x7FFFFFFF else d)
            n = wr.pack(layout.KIND_DATA, self.out_faults, self.seq, self._time_ms(),
                        status | self.out_status, ropes, d, self.out_speed, self.out_batt_mv,
                        self.out_temp_cc)
        self.seq = (self.seq + 1) & 0xFFFFFFFF
        self.ready = False
        return wr.seal_into(n, buf)


def _dan(v):
    """Clamp a daN value into the int16 frame field (ABSENT is reserved)."""
    if v > 32767:
        return 32767
    if v < -32767:
        return -32767
    return v
