# The source of firmware/ropenode/kernel.py and kernel_viper.py (tools/gen_kernel_viper.py
# writes both from it, its helpers expanded inline): edit this file, then run
# .venv/bin/python tools/gen_kernel_viper.py. Under CPython it runs as it is, its helpers called.
"""The per-sample hot path: one function over flat int arrays (docs/model.md).

    P = pack(cfg)           # config: array('i'), layout below
    S = state(cfg)          # state and per-sample outputs: array('i')
    closed = step(S, P, rec, n)   # 1 when a frame window just closed

`step` does, for n ropes: NAMUR and pressure-step checks and calibration (channels), the
positions' travel check and stroke margins, filtered
velocity, pipe-loss table, noise-robust LuGre friction (held back at rest where the seal state
the piston's own travel gives does not support it: do no harm), tension, window
statistics; then oil temperature, depth/speed from the pulse counter and Hall
marks, node time, and at the end of a frame window the frame's fields (OUT_*).
Every int stays within +-2**30, nothing is allocated, and `step` is one call
(a bytecode function with many locals gets its frame from the heap on some
ports; a viper one keeps it on the C stack). S comes first: the native emitter keeps
the first arguments in registers (two of them when loaded from .mpy), and S is the
array read and written most.

It is written in the subset of Python that @micropython.viper compiles with
the same meaning (ints only, no calls, no `not`/`~`/ternaries, arrays read by
index). Its source is tools/kernel_src.py, where the fixed-point idioms `step`
repeats are helpers, each written once: `_q14mul` (a product rounded at 14 bits,
the factor split so neither product is large), `_clamp` and `_divround` (a
rounded quotient split so no intermediate reaches 2**30). tools/gen_kernel_viper.py
expands every call of them inline into this module, the plain build, and into
kernel_viper.py: the same `step` decorated for viper, with each int32 array read
sign-extended (viper reads ptr32 zero-extended on 64-bit ports). Neither build
calls a helper: each sample is still one call of straight-line integer code.
This plain version runs where there is no native emitter (WebAssembly port,
CPython) and is the reference the viper one is tested equal to.
"""
import array

from micropython import const

ROPES_MAX = const(4)
GEXP_POINTS = const(129)
TEMPS_MAX = const(8)
TEMP_ABSENT = const(-32768)  # layout.OIL_TEMP_ABSENT
_BIG = const(0x20000000)     # window min/max start values (|T| < 2**19)

# --- P: config, int32 ---------------------------------------------------------
_ALPHA = const(0)    # velocity filter gain, Q14
_DXMAX = const(1)    # |dx| limit, um/256 per sample
_FSHZ = const(2)     # sample_hz
_FS0 = const(3)      # Fs(p) = FS0 + (p * FSM >> FSS), N
_FSM = const(4)
_FSS = const(5)
_FC0 = const(6)      # Fc(p), N
_FCM = const(7)
_FCS = const(8)
_VS0 = const(9)      # vs(p), um/s
_VSM = const(10)
_VSS = const(11)
_S20 = const(12)     # sigma2(p)
_S2M = const(13)
_S2S = const(14)
_S2S9 = const(15)    # sigma2_shift - 9
_S0M = const(16)     # sigma0 dx: (mul, shift)
_S0S = const(17)
_C1M = const(18)     # c1: (mul, shift - 10)
_C1S10 = const(19)
_PMAX = const(20)    # kPa clamp of the LuGre parameters
_NV = const(21)      # loss table: velocity points
_NT = const(22)      # loss table: temperature rows
_TFIT = const(23)    # oil temperature input fitted (0/1)
_T0C = const(24)     # counts at 0 C
_TMUL = const(25)
_TSH = const(26)
_TLO = const(27)     # temperature input fault limits, counts
_THI = const(28)
_TASSUMED = const(29)  # centi-degC used without a good temperature
_MMPP = const(30)    # mm per pulse, Q16
_MAXP = const(31)    # pulses per sample beyond which the counter glitched
_SNAP = const(32)    # Hall snap distance, mm
_NMARKS = const(33)
_WIN = const(34)     # samples per frame window
_IMB = const(35)     # imbalance limit, per mille of the mean
_BMUL = const(36)    # battery mV = (counts * BMUL) >> BSH
_BSH = const(37)
_BLOW = const(38)    # battery low below this, mV
_FRHZ = const(39)    # frame_hz
_OFORCE = const(40)  # offset of the loss forces in P
_OMARKS = const(41)  # offset of the Hall marks in P
_AZ = const(42)      # LuGre position: gain of the low-pass b, Q14
_TA1 = const(43)     # pressure tracker: the bounce's a1, Q14 (0: no tracker)
_KSH = const(44)     # hydraulic compliance shift
_WARMN = const(45)   # samples of warm-up of b after the start
_AE = const(46)      # balancing strokes: gain of the low-passes of e and of the common motion, Q14
_STH = const(47)     # stroke threshold on e, um/256 (0: no stroke tracking)
_SVMIN = const(48)   # common motion below this is no direction, um/65536 per sample
_SSET = const(49)    # samples of one direction before a stroke is looked for
_AL = const(50)      # rest hold: gain of the slow low-pass x_l, Q14
_AA = const(51)      # rest hold: gain of the activity low-pass, Q14
_TA2 = const(52)     # pressure tracker: the bounce's a2, Q14
_TK = const(53)      # its Kalman gains (4): of c in Q14, v in Q(14 + TVSH), b0, b1 in Q(14 + TBSH)
_TVSH = const(57)    # v is held 2**TVSH finer than c
_TBSH = const(58)    # b is held 2**TBSH finer than c
_NREF = const(59)    # noise following: the channels' noise level the plays are sized for, kPa/16 Q6 (0: fixed)
_NSH = const(60)     # its low-pass gain is 2**-NSH
_SLO = const(61)     # slide following: |e| from which e's take-over is seal travel, um/256
_SSPAN = const(62)   # and over which its share rises to all of it, um/256 (0: off)
_PREC = const(63)    # samples of plausible steps after an implausible pressure step before the channel is good
_HPLAY = const(64)   # do no harm: the play of the measured seal state, um/256 (0: off)
_AREA = const(65)    # cylinder area per rope over the ropes' mean, Q8
_KQ = const(_AREA + ROPES_MAX)  # hydraulic compliance per rope, (um/256 per kPa) * 2**KSH
_PLAYS = const(_KQ + ROPES_MAX)  # LuGre play half-width, um/256, with 1..n healthy pressure channels
_RPLAYS = const(_PLAYS + ROPES_MAX)  # the play while quiet, um/256, with 1..n healthy channels
_RTH = const(_RPLAYS + ROPES_MAX)  # activity below which a rope is quiet, um/65536 (0: no rest hold)
_PCAL = const(_RTH + ROPES_MAX)  # 10 ints per rope (config.py order)
_DCAL = const(_PCAL + 10 * ROPES_MAX)    # 8 ints per rope: the channel's 6 (config.py order; its count
# limits narrowed to the cylinder's travel by `pack`), then stroke_lo, stroke_hi (um/256)
_GEXP = const(_DCAL + 8 * ROPES_MAX)     # exp(-u^2), Q14
_TEMPS = const(_GEXP + GEXP_POINTS)      # loss table temperatures, centi-degC
_VBP = const(_TEMPS + TEMPS_MAX)         # loss velocity points, then forces, then marks

# --- S: state and outputs, int32 ------------------------------------------------
SEEN = const(0)        # bit i / 4+i: a good pressure / displacement value was read once
_STARTED = const(1)    # bit i: filtered position initialised
FAULTS = const(2)      # this sample's fault mask (bit i pressure, 4+i displacement)
GOOD = const(3)        # bit i: rope i has a tension this sample
WFAULTS = const(4)     # OR of the window's fault masks
BATT_SUM = const(5)    # battery counts summed over the window
TEMP_CC = const(6)     # oil temperature, centi-degC, or TEMP_ABSENT
_LT_CC = const(7)      # temperature the loss rows were selected for
_TROW = const(8)       # lower loss row
_TW = const(9)         # weight of the upper row, Q10
DEPTH_MM = const(10)
_FRAC = const(11)      # depth fraction, mm/65536
_PREV_COUNT = const(12)  # -1 until the first counter word
_PREV_HALL = const(13)
WIN_Q16 = const(14)    # travel this window, mm/65536
WIN_PULSES = const(15)  # |pulses| this window
LAST_WIN_PULSES = const(16)
SHAFT_FAULT = const(17)  # latched until the window closes
MARKS_SEEN = const(18)
SUB = const(19)        # node time: samples into the second
SEC = const(20)        # node time: whole seconds
IN_WINDOW = const(21)
P_KPA16 = const(24)    # per rope (ROPES_MAX each): sensor pressure, kPa/16 (kPa: >> 4)
RAW_N = const(28)      # p_tap A, N
X_Q8UM = const(32)     # piston position, um/256
XF_Q8UM = const(36)    # filtered position
DX_Q8UM = const(40)    # this sample's increment
V_UM_S = const(44)     # piston velocity
LOSS_N = const(48)     # dp A, N
ZF = const(52)         # sigma0 z, N/16
_WREM = const(56)      # error-feedback remainder of w
G = const(60)          # g(v), N/16
FRIC_Q4 = const(64)    # F, N/16
FRIC_N = const(68)     # F, N
TENSION_N = const(72)  # compensated tension, N (valid where GOOD)
SUM_N = const(76)      # window sums, N
MIN_N = const(80)
MAX_N = const(84)
SUM_KPA = const(88)
COUNT = const(92)      # healthy samples in the window
OUT_ROPES = const(96)  # the closed window, per rope: mean, min, max (daN), raw p mean (kPa)
OUT_FLAGS = const(112)  # FLAG_* of the closed window
OUT_FAULTS = const(113)  # OR of the window's fault masks
OUT_SPEED = const(114)  # mm/s over the window, clamped to +-32767
OUT_BATT_MV = const(115)
OUT_TEMP_CC = const(116)
OUT_SEC = const(117)   # node time at the window's end
OUT_SUB = const(118)
OUT_DEPTH_MM = const(119)
XS_Q8UM = const(120)   # per rope: the LuGre's position (sum of its increments), um/256
XP_Q8UM = const(124)   # its play output
_PL_Q8 = const(128)     # per rope: the tracker's pressure p_l it took last, kPa/256
_XB_Q8UM = const(132)   # b: low-pass of x_f - k p_l, um/256
_XBREM = const(136)    # its error-feedback remainder
_XH_Q8UM = const(140)   # x_h = k p_l + b
_WARM = const(144)     # samples since the start, up to the warm-up length
_MOT = const(148)      # per rope: this sample's k dp_l, um/256
_E = const(152)        # per rope: low-pass of x_f - x_h, um/256
_CL = const(156)       # low-pass of the common motion sum(area k dp_l), um/65536 per sample
_SMODE = const(157)    # 0, or 1 + the rope whose piston slides alone (a stroke)
_SSGN = const(158)     # direction of the common motion (+-1, 0 unknown)
_SCNT = const(159)     # samples since that direction began, up to _SSET
_XL = const(160)       # per rope: the rest hold's slow low-pass x_l of x_s, um/256
_XLREM = const(164)    # its error-feedback remainder
_ACT = const(168)      # per rope: low-pass of |x_s - x_l|, um/65536 (quiet below _RTH)
_TON = const(172)      # pressure tracker running (0: starts at the next median)
_TC = const(173)       # its creep c, kPa/2048
_TV = const(174)       # the creep's rate c_k - c_(k-1), kPa/2048 / 2**TVSH per sample
_TB0 = const(175)      # its bounce b_k, kPa/2048 / 2**TBSH
_TB1 = const(176)      # b_(k-1)
_NP1 = const(177)      # per rope: noise following: the pressure one sample ago, kPa/16
_NP2 = const(181)      # two samples ago
_NL = const(185)       # the channel's noise level: low-pass of the clipped |second difference|, kPa/16 Q6
_NLREM = const(189)    # its error-feedback remainder
_NRUN = const(193)     # 2 bits per rope: samples (0..2) the channel has been healthy before this one
NOISE_Q10 = const(194)  # the median level over _NREF, Q10 (1024: as commissioned): it scales the plays
_PPREV = const(195)    # per rope: the pressure channel's last count within NAMUR, -1 after none
_PBAD = const(199)     # per rope: samples of plausible steps still needed after an implausible one
_TOREM = const(203)    # per rope: error-feedback remainder of the take-over, um/256 / 256
_TRREM = const(207)    # per rope: that of its slide-following share
_XSUM = const(211)     # per rope: the window's sum of the healthy positions, um (rounded)
_XCNT = const(215)     # per rope: the window's samples with a healthy displacement
_WSTROKE = const(219)  # the window's stroke mask (OR over its samples)
OUT_POS = const(220)   # the closed window, per rope: mean position, 0.1 mm, or POS_ABSENT
OUT_STROKE = const(224)  # its stroke mask: bit i at the low (retracted) end, 4+i at the high
ZM = const(225)        # per rope: do no harm: the seal state the piston's own travel gives, N/16
_XPM = const(229)      # its play output of x_f, um/256
_WREMM = const(233)    # its elastic step's error-feedback remainder
_WHELD = const(237)    # the window's held-back mask (OR over its samples): bit i rope i
OUT_HELD = const(238)  # the closed window's held-back mask
_S_LEN = const(239)

FLAG_IMBALANCE = const(1)    # a rope's mean deviates from the ropes' mean beyond _IMB
FLAG_BATTERY_LOW = const(2)
FLAG_SPEED_FAULT = const(4)  # counter glitch, or a Hall mark with no pulses
TENSION_ABSENT = const(-32768)  # layout.TENSION_ABSENT
RAW_KPA_ABSENT = const(0xFFFF)  # layout.RAW_KPA_ABSENT
POS_ABSENT = const(-32768)      # layout.POS_ABSENT


def pack(c):
    """The config array P from a validated config.Config."""
    n = c.ropes
    nv = c.loss_nv
    nt = c.loss_nt
    nm = len(c.marks_mm)
    p = array.array("i", bytes(4 * (_VBP + n * nv + n * nt * nv + nm)))
    head = (c.alpha_q14, c.dx_max_q8um, c.sample_hz) + c.fs_n + c.fc_n + c.vs_um_s + c.sigma2_q + (
        c.sigma2_shift - 9, c.sigma0_mul, c.sigma0_shift, c.c1_mul, c.c1_shift - 10, c.p_kpa_max,
        nv, nt, c.fitted, c.counts_at_0c, c.cc_mul, c.cc_shift, c.fault_lo_counts, c.fault_hi_counts,
        c.assumed_cc, c.mm_per_pulse_q16, c.max_pulses_per_sample, c.snap_mm, nm, c.window,
        c.imbalance_permille, c.battery_mv_mul, c.battery_mv_shift, c.battery_low_mv, c.frame_hz,
        _VBP + n * nv, _VBP + n * nv + n * nt * nv) + (c.alpha_z_q14, c.tracker_a1_q14,
        c.compliance_shift, c.warmup_samples, c.alpha_e_q14, c.stroke_q8um, c.stroke_vmin_q16,
        c.stroke_settle, c.alpha_l_q14, c.alpha_a_q14, c.tracker_a2_q14) + tuple(c.tracker_k_q14) + (
        c.tracker_v_shift, c.tracker_b_shift, c.noise_ref_q6, c.noise_shift, c.slide_lo_q8um,
        c.slide_span_q8um, c.step_recover, c.hold_play_q8um)
    for j in range(len(head)):
        p[j] = head[j]
    for src, off in ((c.area_q8, _AREA), (c.compliance_q, _KQ), (c.play_q8um, _PLAYS),
                     (c.rest_play_q8um, _RPLAYS), (c.rest_q16um, _RTH), (c.pressure, _PCAL), (c.gexp_q14, _GEXP),
                     (c.temps_cc, _TEMPS), (c.v_um_s, _VBP), (c.force_n, p[_OFORCE]),
                     (c.marks_mm, p[_OMARKS])):
        for j in range(len(src)):
            p[off + j] = src[j]
    # the displacement channels: a position beyond the cylinder's travel is a fault like a
    # count beyond the loop's limits, and positions rise with the counts, so the travel
    # limits become count limits here (the counts whose position is within the travel)
    for i in range(n):
        b = _DCAL + 8 * i
        ch = c.displacement[6 * i:6 * i + 6]
        for j in range(6):
            p[b + j] = ch[j]
        p[b + 1] = _above(ch, c.travel_lo_q8um[i] - 1)
        p[b + 2] = _above(ch, c.travel_hi_q8um[i]) - 1
        p[b + 6] = c.stroke_lo_q8um[i]
        p[b + 7] = c.stroke_hi_q8um[i]
    return p


def _above(ch, x):
    """The least count within the fault limits of displacement channel `ch` (its 6 config
    ints) whose position is above x (um/256), or one past them when none is: positions
    rise with the counts (q8um_mul >= 0)."""
    lo = ch[1]
    hi = ch[2] + 1
    while lo < hi:
        m = (lo + hi) >> 1
        if ch[3] + (((m - ch[0]) * ch[4]) >> ch[5]) > x:
            hi = m
        else:
            lo = m + 1
    return lo


def state(c):
    """A fresh state array S for config c (window min/max open, no counter word yet)."""
    s = array.array("i", bytes(4 * _S_LEN))
    s[TEMP_CC] = TEMP_ABSENT
    s[_LT_CC] = -_BIG  # no loss rows selected yet
    s[DEPTH_MM] = c.start_depth_mm
    s[_PREV_COUNT] = -1
    for i in range(ROPES_MAX):
        s[MIN_N + i] = _BIG
        s[MAX_N + i] = -_BIG
        s[_NL + i] = c.noise_ref_q6
        s[_PPREV + i] = -1
    s[NOISE_Q10] = 1024
    return s


def _q14mul(x, a):
    """x a / 2**14 rounded (halves up), x split at 14 bits: the products are (x >> 14) a and
    (x & 16383) a, so |x| |a| / 2**14 and 2**14 |a| bound them."""
    return (x >> 14) * a + (((x & 16383) * a + 8192) >> 14)


def _clamp(x, lo, hi):
    """x held within lo .. hi (lo <= hi); called only as `x = _clamp(x, lo, hi)`."""
    if x > hi:
        x = hi
    elif x < lo:
        x = lo
    return x


def _divround(a, b, d):
    """a b / d rounded (halves up) for 0 <= a < 2**20, 0 <= b < 2**19 and b < d < 2**20: b split
    into its 9 high and 10 low bits, so no intermediate reaches 2**30; called only as
    `q = _divround(a, b, d)` (q1, q2, q3, r2, r3 its scratch names, used nowhere else in step)."""
    q = a * (b >> 10)
    q1 = q // d
    q = (q - q1 * d) << 10
    q2 = q // d
    r2 = q - q2 * d
    q = a * (b & 1023)
    q3 = q // d
    r3 = q - q3 * d
    q = (q1 << 10) + q2 + q3 + (r2 + r3 + (d >> 1)) // d
    return q


def step(S, P, rec, n):
    """Process one record (2n+4 words); return 1 when a frame window just closed."""
    # channels: counts -> kPa, N, um/256; NAMUR NE43 limits; an implausible pressure step
    # (docs/model.md): a count more than step_max_counts from the last one within NAMUR
    # faults the channel until its steps have been plausible for _PREC samples (its value
    # held, as for a NAMUR fault)
    mask = 0
    seen = S[SEEN]
    for i in range(n):
        c = rec[i]
        b = _PCAL + 10 * i
        if c < P[b + 1] or c > P[b + 2]:
            mask |= 1 << i
            S[_PPREV + i] = -1
        else:
            d = S[_PPREV + i]
            S[_PPREV + i] = c
            if d >= 0 and P[b + 9] != 0:
                d -= c
                if d > P[b + 9] or d < -P[b + 9]:
                    S[_PBAD + i] = P[_PREC]
                elif S[_PBAD + i] > 0:
                    S[_PBAD + i] -= 1
            if S[_PBAD + i] > 0:
                mask |= 1 << i
            else:
                d = c - P[b]
                S[P_KPA16 + i] = (P[b + 3] << 4) + ((d * P[b + 4]) >> (P[b + 5] - 4))  # kpa_shift >= 4
                S[RAW_N + i] = P[b + 6] + ((d * P[b + 7]) >> P[b + 8])
                seen |= 1 << i
        # the position: outside the count limits (the loop's, narrowed to the cylinder's
        # travel) a displacement fault, its value held, never a stroke bit; healthy, it
        # enters the window's stroke mask and its mean (um, rounded: |x| < 2**17 um, so a
        # window's sum < 2**28)
        c = rec[n + i]
        b = _DCAL + 8 * i
        if c < P[b + 1] or c > P[b + 2]:
            mask |= 16 << i
        else:
            d = P[b + 3] + (((c - P[b]) * P[b + 4]) >> P[b + 5])
            S[X_Q8UM + i] = d
            seen |= 16 << i
            if d <= P[b + 6]:
                S[_WSTROKE] |= 1 << i
            elif d >= P[b + 7]:
                S[_WSTROKE] |= 16 << i
            S[_XSUM + i] += (d + 128) >> 8
            S[_XCNT + i] += 1
    S[SEEN] = seen
    S[FAULTS] = mask
    allb = (1 << n) - 1
    dgood = ((mask >> 4) ^ allb) & (seen >> 4) & allb
    good = (mask ^ allb) & dgood & seen & allb
    S[GOOD] = good
    S[_STARTED] &= good  # after a loop fault the position filters start again (not the seal state)
    S[WFAULTS] |= mask

    # oil temperature (centi-degC) and the loss table rows it selects
    rb = n << 1  # the words after the ropes: battery, temperature, counter, Hall
    c = rec[rb + 1]
    t = TEMP_ABSENT
    if P[_TFIT] != 0 and c != 0xFFFF and c >= P[_TLO] and c <= P[_THI]:
        t = ((c - P[_T0C]) * P[_TMUL]) >> P[_TSH]
    S[TEMP_CC] = t
    if t == TEMP_ABSENT:
        t = P[_TASSUMED]
    nt = P[_NT]
    if t != S[_LT_CC]:
        S[_LT_CC] = t
        if nt == 1 or t <= P[_TEMPS]:
            S[_TROW] = 0
            S[_TW] = 0
        elif t >= P[_TEMPS + nt - 1]:
            S[_TROW] = nt - 2
            S[_TW] = 1024
        else:
            j = 0
            while t >= P[_TEMPS + j + 1]:
                j += 1
            S[_TROW] = j
            S[_TW] = ((t - P[_TEMPS + j]) << 10) // (P[_TEMPS + j + 1] - P[_TEMPS + j])
    row = S[_TROW]
    tw = S[_TW]
    S[BATT_SUM] += rec[rb]

    alpha = P[_ALPHA]
    dxmax = P[_DXMAX]
    fshz = P[_FSHZ]
    nv = P[_NV]
    oforce = P[_OFORCE]
    pmax = P[_PMAX]
    s0m = P[_S0M]
    s0s = P[_S0S]
    s0h = 0  # half of 2**s0s, for rounding (2**30 itself is no small int)
    if s0s > 0:
        s0h = 1 << (s0s - 1)
    hp = P[_HPLAY]
    # where the model is right zm still parts from zf: its elastic step follows x_f's noise (sigma0
    # times it, within sigma0 hp) and its dissipation waits for x_f to cross the play (sigma0 hp
    # more), so within twice sigma0 hp of zm the channels do not contradict the model (N/16;
    # hp <= dx_max, so < 2**20)
    ht = ((hp * s0m + s0h) >> s0s) << 1
    c1m = P[_C1M]
    c1s10 = P[_C1S10]
    c1half = (1 << c1s10) >> 1
    s2s9 = P[_S2S9]
    s2half = (1 << s2s9) >> 1
    az = P[_AZ]
    ksh4 = P[_KSH] - 4
    ksh8 = P[_KSH] + 8
    warm = P[_WARMN]
    ae = P[_AE]
    # the LuGre position's pressure part first (docs/model.md): the cavities share their
    # oil, so it takes the median of the healthy pressure channels (0.55 of one channel's
    # noise with four, and one stuck or drifting transmitter does not move it): pm, twice
    # the median in kPa/16, from each channel's rank (no sorting, no allocation)
    # (without a compliance k p_l is 0 whatever p_l is: no median taken)
    pg = ((mask & allb) ^ allb) & seen & allb
    m = 0
    for i in range(n):
        if P[_KQ + i] != 0:
            m = 1
    if m == 0:
        pg = 0
    m = 0
    for i in range(n):
        m += (pg >> i) & 1
    # noise following (docs/model.md): each healthy channel's level, the low-pass (gain
    # 2**-NSH, error feedback) of |p_k - 2 p_k-1 + p_k-2| in kPa/16 clipped at 4 times the
    # level, held within half to twice NREF (Q6: |d| << 6 <= 2**21); the median of the
    # healthy channels' levels over NREF is the noise ratio r (Q10, 512 .. 2048). Then lo
    # and hi: the ranks of the pressure median's middle one or two
    nref = P[_NREF]
    r = S[NOISE_Q10]
    if nref != 0:
        nsh = P[_NSH]
        run = S[_NRUN]
        t = 0  # the healthy channels' levels: sum, least, largest (the median from them)
        lo = nref + nref + 1  # above any level
        hi = 0
        for i in range(n):
            k = (run >> (i + i)) & 3
            run -= k << (i + i)
            if (pg >> i) & 1:
                c = S[P_KPA16 + i]
                lv = S[_NL + i]
                if k == 2:
                    d = c - S[_NP1 + i] - S[_NP1 + i] + S[_NP2 + i]
                    if d < 0:
                        d = -d
                    if d > (lv >> 4):
                        d = lv >> 4
                    e = (d << 6) - lv + S[_NLREM + i]
                    lv += e >> nsh
                    S[_NLREM + i] = e & ((1 << nsh) - 1)
                    lv = _clamp(lv, nref >> 1, nref + nref)
                    S[_NL + i] = lv
                else:
                    k += 1
                S[_NP2 + i] = S[_NP1 + i]
                S[_NP1 + i] = c
                t += lv
                if lv < lo:
                    lo = lv
                if lv > hi:
                    hi = lv
            else:
                k = 0
            run += k << (i + i)
        S[_NRUN] = run
        # twice the median (< 2**21): of 4 the sum of the middle two, of 3 twice the
        # middle one, of 2 the sum, of 1 twice the one
        if m == 4:
            t = t - lo - hi
        elif m == 3:
            t = (t - lo - hi) << 1
        elif m == 1:
            t = t << 1
        if m > 0:
            r = (t << 9) // nref
            S[NOISE_Q10] = r
    lo = (m - 1) >> 1
    hi = m >> 1
    # the play, and the rest hold's play and threshold, for the noise of this median: of
    # fewer channels it is noisier (without a compliance every entry is the same), times r
    # (rounded; split so no product exceeds 2**25)
    j = n - 1
    if m > 0:
        j = m - 1
    play = P[_PLAYS + j]
    rplay = P[_RPLAYS + j]
    rth = P[_RTH + j]
    if r != 1024:
        play = (play >> 10) * r + (((play & 1023) * r + 512) >> 10)
        rplay = (rplay >> 10) * r + (((rplay & 1023) * r + 512) >> 10)
        rth = (rth >> 10) * r + (((rth & 1023) * r + 512) >> 10)
    al = P[_AL]
    aa = P[_AA]
    pm = 0
    for i in range(n):
        if (pg >> i) & 1:
            c = S[P_KPA16 + i]
            r = 0
            for j in range(n):
                if j != i and (pg >> j) & 1:
                    t = S[P_KPA16 + j]
                    if t < c or (t == c and j < i):
                        r += 1
            if r == lo:
                pm += c
            if r == hi:
                pm += c
    # the pressure tracker (docs/model.md): a steady-state Kalman filter of the median,
    # y = pm << 6 in kPa/2048 (|p| <= 100000 kPa: |y| < 2**28), as a creep c at the rate v
    # plus the rope bounce b, a damped oscillator; p_l = c + b0 (kPa/256). It starts afresh
    # at the first median after none. Products split at 14 bits: |x| < 2**28, |gain| < 2**15
    if m > 0:
        y = pm << 6
        if S[_TON] == 0:
            S[_TON] = 1
            S[_TC] = y
            S[_TV] = 0
            S[_TB0] = 0
            S[_TB1] = 0
        else:
            a = P[_TVSH]
            t = S[_TC] + ((S[_TV] + ((1 << a) >> 1)) >> a)
            b0 = S[_TB0]
            b1 = S[_TB1]
            a = P[_TA1]
            d = _q14mul(b0, a)
            a = P[_TA2]
            d -= _q14mul(b1, a)
            S[_TB1] = b0
            e = y - t - (d >> P[_TBSH])
            e = _clamp(e, -0x10000000, 0x10000000)  # a step of 131 MPa: beyond any pressure
            a = P[_TK]
            t += _q14mul(e, a)
            a = P[_TK + 1]
            c1 = S[_TV] + _q14mul(e, a)
            a = P[_TK + 2]
            d += _q14mul(e, a)
            a = P[_TK + 3]
            b1 = S[_TB1] + _q14mul(e, a)
            # c and v within +-2**28, the bounce within +-2**26, as held
            t = _clamp(t, -0x10000000, 0x10000000)
            c1 = _clamp(c1, -0x10000000, 0x10000000)
            d = _clamp(d, -0x4000000, 0x4000000)
            b1 = _clamp(b1, -0x4000000, 0x4000000)
            S[_TC] = t
            S[_TV] = c1
            S[_TB0] = d
            S[_TB1] = b1
    else:
        S[_TON] = 0
    pk = (S[_TC] + (S[_TB0] >> P[_TBSH]) + 4) >> 3
    pk = _clamp(pk, -25600000, 25600000)  # p_l a pressure within +-100000 kPa, as the median is (< 2**25)
    # k p_l split at 12 bits (k < 2**17; 1 kPa steps would move the tension by up to 90 N),
    # and its step this sample; their sum over the ropes, weighted by area, is the oil's
    # common motion
    cv = 0
    allw = 1  # every rope healthy, started before and warmed up: cv is whole
    for i in range(n):
        if (good >> i) & 1:
            kq = P[_KQ + i]
            if ((S[_STARTED] >> i) & 1) == 0:
                x = S[X_Q8UM + i]
                S[XF_Q8UM + i] = x
                S[XS_Q8UM + i] = x
                S[XP_Q8UM + i] = x
                S[_XH_Q8UM + i] = x
                S[_XL + i] = x
                S[_XLREM + i] = 0
                S[_ACT + i] = 0x400000  # 64 um: not quiet until the activity has settled
                pl = pk
                S[_PL_Q8 + i] = pl
                S[_XB_Q8UM + i] = x - (((pl >> 12) * kq >> ksh4) + (((pl & 4095) * kq) >> ksh8))
                S[_XBREM + i] = 0
                S[_WARM + i] = 0
                S[_E + i] = 0
                S[_XPM + i] = x
                S[_WREMM + i] = 0
                S[_STARTED] |= 1 << i
                allw = 0
            pl = S[_PL_Q8 + i]
            m = ((pl >> 12) * kq >> ksh4) + (((pl & 4095) * kq) >> ksh8)
            pl = pk
            S[_PL_Q8 + i] = pl
            m = ((pl >> 12) * kq >> ksh4) + (((pl & 4095) * kq) >> ksh8) - m
            m = _clamp(m, -dxmax, dxmax)
            S[_MOT + i] = m
            cv += m * P[_AREA + i]  # |cv| < 4 * 2**18 * 384 < 2**29
            if S[_WARM + i] < warm:
                allw = 0
        else:
            allw = 0
    if P[_STH] == 0:
        allw = 0
    # a balancing stroke (docs/model.md): the piston of rope mode-1 slides and the others
    # stand; the sliding one's x_h keeps its own share of the motion and its b stands
    mode = S[_SMODE]
    if allw == 0:
        mode = 0
    # the hoist at rest: no shaft pulse in this window so far nor in the last (do no harm)
    rest = 0
    if S[WIN_PULSES] == 0 and S[LAST_WIN_PULSES] == 0:
        rest = 1
    for i in range(n):
        # velocity: x_f += alpha (x - x_f), increment clamped to +-dx_max
        dx = 0
        v = 0
        dxs = 0
        dxp = 0
        vz = 0
        avz = 0
        if (good >> i) & 1:
            x = S[X_Q8UM + i]
            kq = P[_KQ + i]
            e = x - S[XF_Q8UM + i]  # |e| < 2**26: positions are within +-2**25
            # e * alpha / 2**14 rounded, split so no product exceeds 2**28
            dx = _q14mul(e, alpha)
            dx = _clamp(dx, -dxmax, dxmax)
            xf = S[XF_Q8UM + i] + dx
            S[XF_Q8UM + i] = xf
            v = (dx * fshz + 128) >> 8
            # the LuGre's position x_h = k p_l + b (docs/model.md)
            pl = S[_PL_Q8 + i]
            kp = ((pl >> 12) * kq >> ksh4) + (((pl & 4095) * kq) >> ksh8)
            # the rest hold (docs/model.md): how quiet, 0 .. 256, by the activity of the last
            # sample: all of it below rth, none from 2 rth (rth < 2**21, so the shift stays
            # below 2**29)
            qt = 0
            if rth != 0:
                e = S[_ACT + i]
                if e <= rth:
                    qt = 256
                elif e < rth + rth:
                    qt = ((rth + rth - e) << 8) // rth
            a = az
            if mode > 0:  # in a stroke the stopped ropes' b takes back their share
                if i != mode - 1:
                    t = S[_XB_Q8UM + i] - S[_MOT + i]
                    t = _clamp(t, -0x4000000, 0x4000000)  # a position: within +-2**26 whatever the stream
                    S[_XB_Q8UM + i] = t
                else:
                    a = 0  # and the sliding one's b stands
            # b: low-pass of x_f - k p_l with error feedback (a slow b has no dead band),
            # a running mean during the warm-up (|e| < 2**28)
            e = xf - kp - S[_XB_Q8UM + i]
            w = S[_WARM + i]
            if w < warm:
                S[_WARM + i] = w + 1
                a = 16384 // (w + 1)
                if a < az:
                    a = az
            elif qt != 0:  # quiet: b stands, its wander is no seal travel
                a = (a * (256 - qt)) >> 8
            t = (e & 16383) * a + S[_XBREM + i]
            inc = (e >> 14) * a + (t >> 14)
            S[_XBREM + i] = t & 16383
            S[_XB_Q8UM + i] += inc
            xh = kp + S[_XB_Q8UM + i]
            dxs = xh - S[_XH_Q8UM + i]
            S[_XH_Q8UM + i] = xh
            # e: low-pass of x_f - x_h, where a stroke shows (|e| < 2**28)
            e = xf - xh - S[_E + i]
            S[_E + i] += _q14mul(e, ae)
            if w < warm:
                dxs -= inc  # b settles from the first sample's noise: not seal travel
            dxs = _clamp(dxs, -dxmax, dxmax)
            xs = S[XS_Q8UM + i] + dxs
            S[XS_Q8UM + i] = xs
            vz = (dxs * fshz + 128) >> 8  # v of x_s, um/s: noise barely moves it
            avz = vz  # |v_s| for g
            if avz < 0:
                avz = -avz
            # the rest hold's play widens with qt; its activity: the low-pass of |x_s - x_l|,
            # x_l a slower low-pass of x_s (error feedback; |e| < 2**27), in um/65536 with
            # |x_s - x_l| clamped to 64 um (|e| <= 2**22)
            wp = play + (((rplay - play) * qt) >> 8)  # (rplay - play < 2**20)
            if rth != 0:  # (no rest hold: threshold 0)
                e = xs - S[_XL + i]
                t = (e & 16383) * al + S[_XLREM + i]
                S[_XL + i] += (e >> 14) * al + (t >> 14)
                S[_XLREM + i] = t & 16383
                e = xs - S[_XL + i]
                if e < 0:
                    e = -e
                if e > 16384:
                    e = 16384
                e = (e << 8) - S[_ACT + i]
                S[_ACT + i] += _q14mul(e, aa)
            e = S[XP_Q8UM + i]
            if xs > e + wp:
                dxp = xs - wp - e
            elif xs < e - wp:
                dxp = xs + wp - e
            S[XP_Q8UM + i] = e + dxp
        S[DX_Q8UM + i] = dx
        S[V_UM_S + i] = v
        # the velocity of the pipe loss and the viscous term: with a compliance that of x_s
        # (from the pressure: the displacement's noise would pass through both)
        if P[_KQ + i] != 0:
            v = vz
        av = v
        if v < 0:
            av = -v

        # pipe loss dp A: linear in |v| (flat beyond the table), then in temperature
        b = _VBP + i * nv
        if av >= P[b + nv - 1]:
            j = nv - 2
            fr = 1024
        else:
            j = 0
            while av >= P[b + j + 1]:
                j += 1
            # av < 2**19, so av << 10 < 2**29
            fr = ((av - P[b + j]) << 10) // (P[b + j + 1] - P[b + j])
        r = oforce + (i * nt + row) * nv + j
        f0 = P[r] + (((P[r + 1] - P[r]) * fr + 512) >> 10)
        if tw != 0:
            r += nv
            f1 = P[r] + (((P[r + 1] - P[r]) * fr + 512) >> 10)
            f0 += ((f1 - f0) * tw + 512) >> 10
        if v < 0:
            f0 = -f0
        S[LOSS_N + i] = f0

        # LuGre: parameters linear in the clamped sensor pressure
        p = S[P_KPA16 + i] >> 4
        if p < 0:
            p = 0
        elif p > pmax:
            p = pmax
        fs = P[_FS0] + ((p * P[_FSM]) >> P[_FSS])
        fc = P[_FC0] + ((p * P[_FCM]) >> P[_FCS])
        vs = P[_VS0] + ((p * P[_VSM]) >> P[_VSS])
        s2 = P[_S20] + ((p * P[_S2M]) >> P[_S2S])
        u = (avz << 9) // vs  # |v_s| / vs in Q9; avz < 2**20
        eq = 0
        if u < 2048:
            k = _GEXP + (u >> 4)
            eq = P[k] + (((P[k + 1] - P[k]) * (u & 15) + 8) >> 4)
        g = (fc << 4) + (((fs - fc) * eq + 512) >> 10)
        S[G + i] = g
        # elastic step sigma0 dx_s (remainder fed back: no drift), then the implicit
        # dissipation zf (g / (g + sigma0 |dx_p|)), then |zf| <= g
        wf = dxs * s0m + S[_WREM + i]
        w = wf >> s0s
        S[_WREM + i] = wf - (w << s0s)
        z = S[ZF + i]
        zn = z + w  # |zn| < 2**20: |z| <= g < 2**19, |w| < 2**19 (config.py)
        if dxp < 0:
            dxp = -dxp
        aw = (dxp * s0m + s0h) >> s0s  # <= sigma0 dx_max < 2**19
        if aw != 0 and zn != 0:
            ea = zn
            if zn < 0:
                ea = -zn
            dd = g + aw
            # q = round(ea * aw / dd) for ea < 2**20, aw < 2**19, aw < dd < 2**20; aw split
            # into 9 high and 10 low bits so no intermediate reaches 2**30
            q = _divround(ea, aw, dd)
            if zn > 0:
                zn -= q
            else:
                zn += q
        zn = _clamp(zn, -g, g)
        S[ZF + i] = zn
        d = zn - z  # |d| < 2**20; c1m < 2**19: split d so no product passes 2**29
        f = zn + (((d >> 10) * c1m + (((d & 1023) * c1m) >> 10) + c1half) >> c1s10)
        # sigma2 v: |v| < 2**20 and s2 < 2**18, so v is split at 9 bits
        f += ((v >> 9) * s2 + (((v & 511) * s2) >> 9) + s2half) >> s2s9
        S[FRIC_Q4 + i] = f
        # do no harm (docs/model.md): the seal state zm the piston's own travel gives (x_f
        # through a play of half-width hp, the same LuGre steps as zf); at rest the tension
        # carries of F only what zm holds the same way, and the cut shows in the frame
        if hp != 0 and (good >> i) & 1:
            xf = S[XF_Q8UM + i]
            e = S[_XPM + i]
            t = 0
            if xf > e + hp:
                t = xf - hp - e
            elif xf < e - hp:
                t = xf + hp - e
            S[_XPM + i] = e + t
            wf = dx * s0m + S[_WREMM + i]
            w = wf >> s0s
            S[_WREMM + i] = wf - (w << s0s)
            z = S[ZM + i]
            zm = z + w  # |zm| < 2**20, as zn
            if t < 0:
                t = -t
            aw = (t * s0m + s0h) >> s0s  # t <= |dx| <= dx_max: < 2**19
            if aw != 0 and zm != 0:
                ea = zm
                if zm < 0:
                    ea = -zm
                dd = g + aw
                q = _divround(ea, aw, dd)
                if zm > 0:
                    zm -= q
                else:
                    zm += q
            zm = _clamp(zm, -g, g)
            S[ZM + i] = zm
            if rest != 0:
                e = 0
                if f > 0:
                    w = zm + ht
                    if w < 0:
                        w = 0
                    if f > w:
                        e = f - w
                        f = w
                elif f < 0:
                    w = zm - ht
                    if w > 0:
                        w = 0
                    if f < w:
                        e = w - f
                        f = w
                if e > (g >> 3):
                    S[_WHELD] |= 1 << i
        fn = (f + 8) >> 4
        S[FRIC_N + i] = fn

        # tension and window statistics: |T| < 2**19 (config.TENSION_MAX_N, which the host's
        # builder proves; held here too, so the window sums stay small ints on any config)
        t = S[RAW_N + i] + f0 + fn
        t = _clamp(t, -524287, 524287)
        S[TENSION_N + i] = t
        if (good >> i) & 1:
            S[SUM_N + i] += t
            S[SUM_KPA + i] += S[P_KPA16 + i] >> 4
            S[COUNT + i] += 1
            if t < S[MIN_N + i]:
                S[MIN_N + i] = t
            if t > S[MAX_N + i]:
                S[MAX_N + i] = t

    # balancing strokes (docs/model.md): the direction of the common motion (cl, its
    # low-pass), and a stroke when one rope's e runs ahead in that direction by more
    # than the threshold after the direction held _SSET samples; it ends when the
    # direction turns or a stopped rope's e runs ahead too. A stroke's start and end
    # re-anchor x_h by e, without seal travel (at a start the stopped ropes' e is the
    # stroke rope's lead, shared by area).
    if allw == 0:
        S[_SMODE] = 0
        S[_SSGN] = 0
        S[_SCNT] = 0
        S[_CL] = 0
    else:
        e = cv - S[_CL]  # |e| < 2**30: |cv|, |cl| < 2**29
        c = S[_CL] + _q14mul(e, ae)
        S[_CL] = c
        s = -1
        if c > 0:
            s = 1
        sg = S[_SSGN]
        th = P[_STH]
        re = 0
        if mode == 0:
            # what e holds beyond a quarter of the threshold (noise: 1.6 sigma) is
            # real unequal sharing: x_h takes it over at 1/64 per sample, (4|e| - th) / 256
            # in um/256 / 256 with its remainder carried to the next sample (rounded, a
            # slowly varying take-over would lean one way for seconds); a stroke's e
            # runs faster than that and still shows. Slide following: of that take-over
            # the share f = (|e| - lo) / span (0 .. 1, Q8 rounded) is the piston's proven
            # travel, its remainder carried too (neither remainder is reset at a restart
            # or a stroke: less than a unit): it is left out of x_h, and x_h's next
            # step carries it into x_s (|e| < 2**27: 4|e| < 2**29, c < 2**21,
            # c f < 2**29; d < span <= 2**20: d << 8 < 2**28).
            # lo and hi (the median's ranks, done with) hold lo and span: a new local
            # would cost the viper step's every sample (1.45 -> 3.4 us on the unix port)
            lo = P[_SLO]
            hi = P[_SSPAN]
            for i in range(n):
                t = S[_E + i]
                c = t
                if t < 0:
                    c = -t
                if (c << 2) > th:
                    d = c - lo
                    c = (c << 2) - th + S[_TOREM + i]
                    S[_TOREM + i] = c & 255
                    c = c >> 8
                    r = 0
                    if hi != 0 and d > 0:
                        if d >= hi:
                            r = c
                        else:
                            r = c * (((d << 8) + (hi >> 1)) // hi) + S[_TRREM + i]
                            S[_TRREM + i] = r & 255
                            r = r >> 8
                    if t < 0:
                        c = -c
                        r = -r
                    S[_XB_Q8UM + i] += c
                    S[_XH_Q8UM + i] += c - r
                    S[_E + i] = t - c
            c = S[_CL]
            if c < 0:
                c = -c
            if c > P[_SVMIN] and s != sg:
                S[_SSGN] = s
                S[_SCNT] = 0
            elif S[_SCNT] < P[_SSET]:
                S[_SCNT] += 1
            if c > P[_SVMIN] and S[_SCNT] >= P[_SSET]:
                # a stroke is one piston sliding alone: exactly one rope's e past the
                # threshold (two or more are pistons moving alike, whose e tie within
                # rounding: the float reference could not pick the same one)
                best = 0
                for i in range(n):
                    if S[_E + i] * s > th:
                        if best == 0:
                            best = i + 1
                        else:
                            best = -1
                if best > 0:
                    S[_SMODE] = best
                    re = 1
                    # until the stroke was seen the stopped pistons' x_h went on with the
                    # pressure: their offset is the stroke piston's lead shared by area
                    # (the oil's volume is kept), plus the lag of e, a low-pass, behind
                    # that ramp (the common motion per unit area times (1 - a) / a)
                    so = 0
                    for i in range(n):
                        if i != best - 1:
                            so += P[_AREA + i]
                    if so > 0:
                        # r: its area over the others' in Q8 (<= 768: areas are 128..384);
                        # |e| < 2**28, split at 8 bits
                        r = (P[_AREA + best - 1] << 8) // so
                        t = S[_E + best - 1]
                        lead = (t >> 8) * r + (((t & 255) * r) >> 8)
                        # |cl| clamped to 2**25, then |t| to 2**16 - 1: t * 16383 < 2**30
                        c = S[_CL]
                        c = _clamp(c, -0x2000000, 0x2000000)
                        t = (c << 4) // (so + P[_AREA + best - 1])
                        t = _clamp(t, -65535, 65535)
                        t = -lead - t * (16384 - ae) // (ae << 4)
                        for i in range(n):
                            if i != best - 1:
                                S[_E + i] = t
        else:
            if s != sg:
                re = 1
                S[_SCNT] = 0
            for i in range(n):
                if i != mode - 1 and S[_E + i] * sg > th:  # another piston moves
                    re = 1
            if re != 0:
                S[_SMODE] = 0
                S[_SSGN] = s
        if re != 0:  # a stroke starts or ends: x_h re-anchored by e, without seal travel
            for i in range(n):
                t = S[_E + i]
                S[_XB_Q8UM + i] += t
                S[_XH_Q8UM + i] += t
                S[_E + i] = 0

    # depth from the counter's wrapped difference; Hall marks snap it
    c = rec[rb + 2]
    prev = S[_PREV_COUNT]
    S[_PREV_COUNT] = c
    if prev >= 0:
        d = (c - prev) & 0xFFFF
        if d >= 0x8000:
            d -= 0x10000
        maxp = P[_MAXP]
        if d > maxp or d < -maxp:
            S[SHAFT_FAULT] = 1
        elif d != 0:
            t = d * P[_MMPP]
            S[WIN_Q16] += t
            if d > 0:
                S[WIN_PULSES] += d
            else:
                S[WIN_PULSES] -= d
            f = S[_FRAC] + t
            S[DEPTH_MM] += f >> 16
            S[_FRAC] = f & 0xFFFF
    c = rec[rb + 3] & 3
    if c != 0 and S[_PREV_HALL] == 0:
        S[MARKS_SEEN] += 1
        if S[WIN_PULSES] == 0 and S[LAST_WIN_PULSES] == 0:
            S[SHAFT_FAULT] = 1
        # snap to the nearest mark within SNAP
        dep = S[DEPTH_MM]
        best = -1
        bd = P[_SNAP] + 1
        m = P[_OMARKS]
        for j in range(P[_NMARKS]):
            d = P[m + j] - dep
            if d < 0:
                d = -d
            if d < bd:
                bd = d
                best = j
        if best >= 0:
            S[DEPTH_MM] = P[m + best]
            S[_FRAC] = 0
    S[_PREV_HALL] = c

    # node time and the frame window
    c = S[SUB] + 1
    if c >= fshz:
        c = 0
        S[SEC] += 1
    S[SUB] = c
    c = S[IN_WINDOW] + 1
    if c < P[_WIN]:
        S[IN_WINDOW] = c
        return 0
    S[IN_WINDOW] = 0

    # the window closes: its frame fields, then a new window
    tot = 0
    used = 0
    for i in range(n):
        o = OUT_ROPES + 4 * i
        c = S[COUNT + i]
        if c == 0:
            S[o] = TENSION_ABSENT
            S[o + 1] = TENSION_ABSENT
            S[o + 2] = TENSION_ABSENT
            S[o + 3] = RAW_KPA_ABSENT
        else:
            for j in range(3):  # mean, min, max: N -> daN rounded, clamped to int16 (not ABSENT)
                if j == 0:
                    t = (S[SUM_N + i] + 5 * c) // (10 * c)
                elif j == 1:
                    t = (S[MIN_N + i] + 5) // 10
                else:
                    t = (S[MAX_N + i] + 5) // 10
                t = _clamp(t, -32767, 32767)
                S[o + j] = t
            tot += S[o]
            used += 1
            p = (S[SUM_KPA + i] + (c >> 1)) // c
            if p < 0:
                p = 0
            elif p > 65534:
                p = 65534
            S[o + 3] = p
        S[SUM_N + i] = 0
        S[SUM_KPA + i] = 0
        S[COUNT + i] = 0
        S[MIN_N + i] = _BIG
        S[MAX_N + i] = -_BIG
        # the mean position, um -> 0.1 mm rounded as the tensions are, clamped to int16
        # (not POS_ABSENT); POS_ABSENT without a healthy displacement sample
        c = S[_XCNT + i]
        t = POS_ABSENT
        if c != 0:
            t = (S[_XSUM + i] + 50 * c) // (100 * c)
            t = _clamp(t, -32767, 32767)
        S[OUT_POS + i] = t
        S[_XSUM + i] = 0
        S[_XCNT + i] = 0
    flags = 0
    if used > 1 and tot > 0:
        lim = P[_IMB]
        for i in range(n):
            m = S[OUT_ROPES + 4 * i]
            if m != TENSION_ABSENT:
                d = m * used - tot
                if d < 0:
                    d = -d
                # |m - mean| / mean > lim / 1000, in integers (<= 2**18 * 1000)
                if d * 1000 > lim * tot:
                    flags |= FLAG_IMBALANCE
    # battery: the window's mean counts (< 2**16) to mV
    c = P[_BSH]
    t = ((S[BATT_SUM] // P[_WIN]) * P[_BMUL] + ((1 << c) >> 1)) >> c
    if t < P[_BLOW]:
        flags |= FLAG_BATTERY_LOW
    if t > 65535:
        t = 65535
    S[OUT_BATT_MV] = t
    S[BATT_SUM] = 0
    if S[SHAFT_FAULT] != 0:
        flags |= FLAG_SPEED_FAULT
        S[SHAFT_FAULT] = 0
    # speed over the window, mm/s: win_q16 < 2**29, frame_hz <= 1000
    t = ((S[WIN_Q16] >> 10) * P[_FRHZ]) >> 6
    t = _clamp(t, -32767, 32767)
    S[OUT_SPEED] = t
    S[WIN_Q16] = 0
    S[LAST_WIN_PULSES] = S[WIN_PULSES]
    S[WIN_PULSES] = 0
    S[OUT_FLAGS] = flags
    S[OUT_FAULTS] = S[WFAULTS]
    S[WFAULTS] = 0
    S[OUT_STROKE] = S[_WSTROKE]
    S[_WSTROKE] = 0
    S[OUT_HELD] = S[_WHELD]
    S[_WHELD] = 0
    S[OUT_TEMP_CC] = S[TEMP_CC]
    S[OUT_SEC] = S[SEC]
    S[OUT_SUB] = S[SUB]
    S[OUT_DEPTH_MM] = S[DEPTH_MM]
    return 1
