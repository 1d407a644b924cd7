"""GENERATED from kernel.py by tools/gen_kernel_viper.py: do not edit.

kernel.py with `step` compiled by @micropython.viper (int32 reads sign-extended).
"""
import micropython
import array
from micropython import const
ROPES_MAX = const(4)
GEXP_POINTS = const(129)
TEMPS_MAX = const(8)
TEMP_ABSENT = const(-32768)
_BIG = const(536870912)
_ALPHA = const(0)
_DXMAX = const(1)
_FSHZ = const(2)
_FS0 = const(3)
_FSM = const(4)
_FSS = const(5)
_FC0 = const(6)
_FCM = const(7)
_FCS = const(8)
_VS0 = const(9)
_VSM = const(10)
_VSS = const(11)
_S20 = const(12)
_S2M = const(13)
_S2S = const(14)
_S2S9 = const(15)
_S0M = const(16)
_S0S = const(17)
_C1M = const(18)
_C1S10 = const(19)
_PMAX = const(20)
_NV = const(21)
_NT = const(22)
_TFIT = const(23)
_T0C = const(24)
_TMUL = const(25)
_TSH = const(26)
_TLO = const(27)
_THI = const(28)
_TASSUMED = const(29)
_MMPP = const(30)
_MAXP = const(31)
_SNAP = const(32)
_NMARKS = const(33)
_WIN = const(34)
_IMB = const(35)
_BMUL = const(36)
_BSH = const(37)
_BLOW = const(38)
_FRHZ = const(39)
_OFORCE = const(40)
_OMARKS = const(41)
_AZ = const(42)
_TA1 = const(43)
_KSH = const(44)
_WARMN = const(45)
_AE = const(46)
_STH = const(47)
_SVMIN = const(48)
_SSET = const(49)
_AL = const(50)
_AA = const(51)
_TA2 = const(52)
_TK = const(53)
_TVSH = const(57)
_TBSH = const(58)
_NREF = const(59)
_NSH = const(60)
_SLO = const(61)
_SSPAN = const(62)
_PREC = const(63)
_HPLAY = const(64)
_AREA = const(65)
_KQ = const(_AREA + ROPES_MAX)
_PLAYS = const(_KQ + ROPES_MAX)
_RPLAYS = const(_PLAYS + ROPES_MAX)
_RTH = const(_RPLAYS + ROPES_MAX)
_PCAL = const(_RTH + ROPES_MAX)
_DCAL = const(_PCAL + 10 * ROPES_MAX)
_GEXP = const(_DCAL + 8 * ROPES_MAX)
_TEMPS = const(_GEXP + GEXP_POINTS)
_VBP = const(_TEMPS + TEMPS_MAX)
SEEN = const(0)
_STARTED = const(1)
FAULTS = const(2)
GOOD = const(3)
WFAULTS = const(4)
BATT_SUM = const(5)
TEMP_CC = const(6)
_LT_CC = const(7)
_TROW = const(8)
_TW = const(9)
DEPTH_MM = const(10)
_FRAC = const(11)
_PREV_COUNT = const(12)
_PREV_HALL = const(13)
WIN_Q16 = const(14)
WIN_PULSES = const(15)
LAST_WIN_PULSES = const(16)
SHAFT_FAULT = const(17)
MARKS_SEEN = const(18)
SUB = const(19)
SEC = const(20)
IN_WINDOW = const(21)
P_KPA16 = const(24)
RAW_N = const(28)
X_Q8UM = const(32)
XF_Q8UM = const(36)
DX_Q8UM = const(40)
V_UM_S = const(44)
LOSS_N = const(48)
ZF = const(52)
_WREM = const(56)
G = const(60)
FRIC_Q4 = const(64)
FRIC_N = const(68)
TENSION_N = const(72)
SUM_N = const(76)
MIN_N = const(80)
MAX_N = const(84)
SUM_KPA = const(88)
COUNT = const(92)
OUT_ROPES = const(96)
OUT_FLAGS = const(112)
OUT_FAULTS = const(113)
OUT_SPEED = const(114)
OUT_BATT_MV = const(115)
OUT_TEMP_CC = const(116)
OUT_SEC = const(117)
OUT_SUB = const(118)
OUT_DEPTH_MM = const(119)
XS_Q8UM = const(120)
XP_Q8UM = const(124)
_PL_Q8 = const(128)
_XB_Q8UM = const(132)
_XBREM = const(136)
_XH_Q8UM = const(140)
_WARM = const(144)
_MOT = const(148)
_E = const(152)
_CL = const(156)
_SMODE = const(157)
_SSGN = const(158)
_SCNT = const(159)
_XL = const(160)
_XLREM = const(164)
_ACT = const(168)
_TON = const(172)
_TC = const(173)
_TV = const(174)
_TB0 = const(175)
_TB1 = const(176)
_NP1 = const(177)
_NP2 = const(181)
_NL = const(185)
_NLREM = const(189)
_NRUN = const(193)
NOISE_Q10 = const(194)
_PPREV = const(195)
_PBAD = const(199)
_TOREM = const(203)
_TRREM = const(207)
_XSUM = const(211)
_XCNT = const(215)
_WSTROKE = const(219)
OUT_POS = const(220)
OUT_STROKE = const(224)
ZM = const(225)
_XPM = const(229)
_WREMM = const(233)
_WHELD = const(237)
OUT_HELD = const(238)
_S_LEN = const(239)
FLAG_IMBALANCE = const(1)
FLAG_BATTERY_LOW = const(2)
FLAG_SPEED_FAULT = const(4)
TENSION_ABSENT = const(-32768)
RAW_KPA_ABSENT = const(65535)
POS_ABSENT = const(-32768)

def pack(c):
    """The config array P from a validated config.Config."""
    n = c.ropes
    nv = c.loss_nv
    nt = c.loss_nt
    nm = len(c.marks_mm)
    p = array.array('i', bytes(4 * (_VBP + n * nv + n * nt * nv + nm)))
    head = (c.alpha_q14, c.dx_max_q8um, c.sample_hz) + c.fs_n + c.fc_n + c.vs_um_s + c.sigma2_q + (c.sigma2_shift - 9, c.sigma0_mul, c.sigma0_shift, c.c1_mul, c.c1_shift - 10, c.p_kpa_max, nv, nt, c.fitted, c.counts_at_0c, c.cc_mul, c.cc_shift, c.fault_lo_counts, c.fault_hi_counts, c.assumed_cc, c.mm_per_pulse_q16, c.max_pulses_per_sample, c.snap_mm, nm, c.window, c.imbalance_permille, c.battery_mv_mul, c.battery_mv_shift, c.battery_low_mv, c.frame_hz, _VBP + n * nv, _VBP + n * nv + n * nt * nv) + (c.alpha_z_q14, c.tracker_a1_q14, c.compliance_shift, c.warmup_samples, c.alpha_e_q14, c.stroke_q8um, c.stroke_vmin_q16, c.stroke_settle, c.alpha_l_q14, c.alpha_a_q14, c.tracker_a2_q14) + tuple(c.tracker_k_q14) + (c.tracker_v_shift, c.tracker_b_shift, c.noise_ref_q6, c.noise_shift, c.slide_lo_q8um, c.slide_span_q8um, c.step_recover, c.hold_play_q8um)
    for j in range(len(head)):
        p[j] = head[j]
    for src, off in ((c.area_q8, _AREA), (c.compliance_q, _KQ), (c.play_q8um, _PLAYS), (c.rest_play_q8um, _RPLAYS), (c.rest_q16um, _RTH), (c.pressure, _PCAL), (c.gexp_q14, _GEXP), (c.temps_cc, _TEMPS), (c.v_um_s, _VBP), (c.force_n, p[_OFORCE]), (c.marks_mm, p[_OMARKS])):
        for j in range(len(src)):
            p[off + j] = src[j]
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
        m = lo + hi >> 1
        if ch[3] + ((m - ch[0]) * ch[4] >> ch[5]) > x:
            hi = m
        else:
            lo = m + 1
    return lo

def state(c):
    """A fresh state array S for config c (window min/max open, no counter word yet)."""
    s = array.array('i', bytes(4 * _S_LEN))
    s[TEMP_CC] = TEMP_ABSENT
    s[_LT_CC] = -_BIG
    s[DEPTH_MM] = c.start_depth_mm
    s[_PREV_COUNT] = -1
    for i in range(ROPES_MAX):
        s[MIN_N + i] = _BIG
        s[MAX_N + i] = -_BIG
        s[_NL + i] = c.noise_ref_q6
        s[_PPREV + i] = -1
    s[NOISE_Q10] = 1024
    return s

@micropython.viper
def step(S: ptr32, P: ptr32, rec: ptr16, n: int) -> int:
    """Process one record (2n+4 words); return 1 when a frame window just closed."""
    s31 = 1 << 29
    s31 <<= 2
    mask = 0
    seen = (S[SEEN] ^ s31) - s31
    for i in range(n):
        c = rec[i]
        b = _PCAL + 10 * i
        if c < (P[b + 1] ^ s31) - s31 or c > (P[b + 2] ^ s31) - s31:
            mask |= 1 << i
            S[_PPREV + i] = -1
        else:
            d = (S[_PPREV + i] ^ s31) - s31
            S[_PPREV + i] = c
            if d >= 0 and (P[b + 9] ^ s31) - s31 != 0:
                d -= c
                if d > (P[b + 9] ^ s31) - s31 or d < -((P[b + 9] ^ s31) - s31):
                    S[_PBAD + i] = (P[_PREC] ^ s31) - s31
                elif (S[_PBAD + i] ^ s31) - s31 > 0:
                    S[_PBAD + i] -= 1
            if (S[_PBAD + i] ^ s31) - s31 > 0:
                mask |= 1 << i
            else:
                d = c - ((P[b] ^ s31) - s31)
                S[P_KPA16 + i] = ((P[b + 3] ^ s31) - s31 << 4) + (d * ((P[b + 4] ^ s31) - s31) >> (P[b + 5] ^ s31) - s31 - 4)
                S[RAW_N + i] = (P[b + 6] ^ s31) - s31 + (d * ((P[b + 7] ^ s31) - s31) >> (P[b + 8] ^ s31) - s31)
                seen |= 1 << i
        c = rec[n + i]
        b = _DCAL + 8 * i
        if c < (P[b + 1] ^ s31) - s31 or c > (P[b + 2] ^ s31) - s31:
            mask |= 16 << i
        else:
            d = (P[b + 3] ^ s31) - s31 + ((c - ((P[b] ^ s31) - s31)) * ((P[b + 4] ^ s31) - s31) >> (P[b + 5] ^ s31) - s31)
            S[X_Q8UM + i] = d
            seen |= 16 << i
            if d <= (P[b + 6] ^ s31) - s31:
                S[_WSTROKE] |= 1 << i
            elif d >= (P[b + 7] ^ s31) - s31:
                S[_WSTROKE] |= 16 << i
            S[_XSUM + i] += d + 128 >> 8
            S[_XCNT + i] += 1
    S[SEEN] = seen
    S[FAULTS] = mask
    allb = (1 << n) - 1
    dgood = (mask >> 4 ^ allb) & seen >> 4 & allb
    good = (mask ^ allb) & dgood & seen & allb
    S[GOOD] = good
    S[_STARTED] &= good
    S[WFAULTS] |= mask
    rb = n << 1
    c = rec[rb + 1]
    t = TEMP_ABSENT
    if (P[_TFIT] ^ s31) - s31 != 0 and c != 65535 and (c >= (P[_TLO] ^ s31) - s31) and (c <= (P[_THI] ^ s31) - s31):
        t = (c - ((P[_T0C] ^ s31) - s31)) * ((P[_TMUL] ^ s31) - s31) >> (P[_TSH] ^ s31) - s31
    S[TEMP_CC] = t
    if t == TEMP_ABSENT:
        t = (P[_TASSUMED] ^ s31) - s31
    nt = (P[_NT] ^ s31) - s31
    if t != (S[_LT_CC] ^ s31) - s31:
        S[_LT_CC] = t
        if nt == 1 or t <= (P[_TEMPS] ^ s31) - s31:
            S[_TROW] = 0
            S[_TW] = 0
        elif t >= (P[_TEMPS + nt - 1] ^ s31) - s31:
            S[_TROW] = nt - 2
            S[_TW] = 1024
        else:
            j = 0
            while t >= (P[_TEMPS + j + 1] ^ s31) - s31:
                j += 1
            S[_TROW] = j
            S[_TW] = (t - ((P[_TEMPS + j] ^ s31) - s31) << 10) // ((P[_TEMPS + j + 1] ^ s31) - s31 - ((P[_TEMPS + j] ^ s31) - s31))
    row = (S[_TROW] ^ s31) - s31
    tw = (S[_TW] ^ s31) - s31
    S[BATT_SUM] += rec[rb]
    alpha = (P[_ALPHA] ^ s31) - s31
    dxmax = (P[_DXMAX] ^ s31) - s31
    fshz = (P[_FSHZ] ^ s31) - s31
    nv = (P[_NV] ^ s31) - s31
    oforce = (P[_OFORCE] ^ s31) - s31
    pmax = (P[_PMAX] ^ s31) - s31
    s0m = (P[_S0M] ^ s31) - s31
    s0s = (P[_S0S] ^ s31) - s31
    s0h = 0
    if s0s > 0:
        s0h = 1 << s0s - 1
    hp = (P[_HPLAY] ^ s31) - s31
    ht = hp * s0m + s0h >> s0s << 1
    c1m = (P[_C1M] ^ s31) - s31
    c1s10 = (P[_C1S10] ^ s31) - s31
    c1half = 1 << c1s10 >> 1
    s2s9 = (P[_S2S9] ^ s31) - s31
    s2half = 1 << s2s9 >> 1
    az = (P[_AZ] ^ s31) - s31
    ksh4 = (P[_KSH] ^ s31) - s31 - 4
    ksh8 = (P[_KSH] ^ s31) - s31 + 8
    warm = (P[_WARMN] ^ s31) - s31
    ae = (P[_AE] ^ s31) - s31
    pg = (mask & allb ^ allb) & seen & allb
    m = 0
    for i in range(n):
        if (P[_KQ + i] ^ s31) - s31 != 0:
            m = 1
    if m == 0:
        pg = 0
    m = 0
    for i in range(n):
        m += pg >> i & 1
    nref = (P[_NREF] ^ s31) - s31
    r = (S[NOISE_Q10] ^ s31) - s31
    if nref != 0:
        nsh = (P[_NSH] ^ s31) - s31
        run = (S[_NRUN] ^ s31) - s31
        t = 0
        lo = nref + nref + 1
        hi = 0
        for i in range(n):
            k = run >> i + i & 3
            run -= k << i + i
            if pg >> i & 1:
                c = (S[P_KPA16 + i] ^ s31) - s31
                lv = (S[_NL + i] ^ s31) - s31
                if k == 2:
                    d = c - ((S[_NP1 + i] ^ s31) - s31) - ((S[_NP1 + i] ^ s31) - s31) + ((S[_NP2 + i] ^ s31) - s31)
                    if d < 0:
                        d = -d
                    if d > lv >> 4:
                        d = lv >> 4
                    e = (d << 6) - lv + ((S[_NLREM + i] ^ s31) - s31)
                    lv += e >> nsh
                    S[_NLREM + i] = e & (1 << nsh) - 1
                    if lv > nref + nref:
                        lv = nref + nref
                    elif lv < nref >> 1:
                        lv = nref >> 1
                    S[_NL + i] = lv
                else:
                    k += 1
                S[_NP2 + i] = (S[_NP1 + i] ^ s31) - s31
                S[_NP1 + i] = c
                t += lv
                if lv < lo:
                    lo = lv
                if lv > hi:
                    hi = lv
            else:
                k = 0
            run += k << i + i
        S[_NRUN] = run
        if m == 4:
            t = t - lo - hi
        elif m == 3:
            t = t - lo - hi << 1
        elif m == 1:
            t = t << 1
        if m > 0:
            r = (t << 9) // nref
            S[NOISE_Q10] = r
    lo = m - 1 >> 1
    hi = m >> 1
    j = n - 1
    if m > 0:
        j = m - 1
    play = (P[_PLAYS + j] ^ s31) - s31
    rplay = (P[_RPLAYS + j] ^ s31) - s31
    rth = (P[_RTH + j] ^ s31) - s31
    if r != 1024:
        play = (play >> 10) * r + ((play & 1023) * r + 512 >> 10)
        rplay = (rplay >> 10) * r + ((rplay & 1023) * r + 512 >> 10)
        rth = (rth >> 10) * r + ((rth & 1023) * r + 512 >> 10)
    al = (P[_AL] ^ s31) - s31
    aa = (P[_AA] ^ s31) - s31
    pm = 0
    for i in range(n):
        if pg >> i & 1:
            c = (S[P_KPA16 + i] ^ s31) - s31
            r = 0
            for j in range(n):
                if j != i and pg >> j & 1:
                    t = (S[P_KPA16 + j] ^ s31) - s31
                    if t < c or (t == c and j < i):
                        r += 1
            if r == lo:
                pm += c
            if r == hi:
                pm += c
    if m > 0:
        y = pm << 6
        if (S[_TON] ^ s31) - s31 == 0:
            S[_TON] = 1
            S[_TC] = y
            S[_TV] = 0
            S[_TB0] = 0
            S[_TB1] = 0
        else:
            a = (P[_TVSH] ^ s31) - s31
            t = (S[_TC] ^ s31) - s31 + ((S[_TV] ^ s31) - s31 + (1 << a >> 1) >> a)
            b0 = (S[_TB0] ^ s31) - s31
            b1 = (S[_TB1] ^ s31) - s31
            a = (P[_TA1] ^ s31) - s31
            d = (b0 >> 14) * a + ((b0 & 16383) * a + 8192 >> 14)
            a = (P[_TA2] ^ s31) - s31
            d -= (b1 >> 14) * a + ((b1 & 16383) * a + 8192 >> 14)
            S[_TB1] = b0
            e = y - t - (d >> (P[_TBSH] ^ s31) - s31)
            if e > 268435456:
                e = 268435456
            elif e < -268435456:
                e = -268435456
            a = (P[_TK] ^ s31) - s31
            t += (e >> 14) * a + ((e & 16383) * a + 8192 >> 14)
            a = (P[_TK + 1] ^ s31) - s31
            c1 = (S[_TV] ^ s31) - s31 + (e >> 14) * a + ((e & 16383) * a + 8192 >> 14)
            a = (P[_TK + 2] ^ s31) - s31
            d += (e >> 14) * a + ((e & 16383) * a + 8192 >> 14)
            a = (P[_TK + 3] ^ s31) - s31
            b1 = (S[_TB1] ^ s31) - s31 + (e >> 14) * a + ((e & 16383) * a + 8192 >> 14)
            if t > 268435456:
                t = 268435456
            elif t < -268435456:
                t = -268435456
            if c1 > 268435456:
                c1 = 268435456
            elif c1 < -268435456:
                c1 = -268435456
            if d > 67108864:
                d = 67108864
            elif d < -67108864:
                d = -67108864
            if b1 > 67108864:
                b1 = 67108864
            elif b1 < -67108864:
                b1 = -67108864
            S[_TC] = t
            S[_TV] = c1
            S[_TB0] = d
            S[_TB1] = b1
    else:
        S[_TON] = 0
    pk = (S[_TC] ^ s31) - s31 + ((S[_TB0] ^ s31) - s31 >> (P[_TBSH] ^ s31) - s31) + 4 >> 3
    if pk > 25600000:
        pk = 25600000
    elif pk < -25600000:
        pk = -25600000
    cv = 0
    allw = 1
    for i in range(n):
        if good >> i & 1:
            kq = (P[_KQ + i] ^ s31) - s31
            if (S[_STARTED] ^ s31) - s31 >> i & 1 == 0:
                x = (S[X_Q8UM + i] ^ s31) - s31
                S[XF_Q8UM + i] = x
                S[XS_Q8UM + i] = x
                S[XP_Q8UM + i] = x
                S[_XH_Q8UM + i] = x
                S[_XL + i] = x
                S[_XLREM + i] = 0
                S[_ACT + i] = 4194304
                pl = pk
                S[_PL_Q8 + i] = pl
                S[_XB_Q8UM + i] = x - (((pl >> 12) * kq >> ksh4) + ((pl & 4095) * kq >> ksh8))
                S[_XBREM + i] = 0
                S[_WARM + i] = 0
                S[_E + i] = 0
                S[_XPM + i] = x
                S[_WREMM + i] = 0
                S[_STARTED] |= 1 << i
                allw = 0
            pl = (S[_PL_Q8 + i] ^ s31) - s31
            m = ((pl >> 12) * kq >> ksh4) + ((pl & 4095) * kq >> ksh8)
            pl = pk
            S[_PL_Q8 + i] = pl
            m = ((pl >> 12) * kq >> ksh4) + ((pl & 4095) * kq >> ksh8) - m
            if m > dxmax:
                m = dxmax
            elif m < -dxmax:
                m = -dxmax
            S[_MOT + i] = m
            cv += m * ((P[_AREA + i] ^ s31) - s31)
            if (S[_WARM + i] ^ s31) - s31 < warm:
                allw = 0
        else:
            allw = 0
    if (P[_STH] ^ s31) - s31 == 0:
        allw = 0
    mode = (S[_SMODE] ^ s31) - s31
    if allw == 0:
        mode = 0
    rest = 0
    if (S[WIN_PULSES] ^ s31) - s31 == 0 and (S[LAST_WIN_PULSES] ^ s31) - s31 == 0:
        rest = 1
    for i in range(n):
        dx = 0
        v = 0
        dxs = 0
        dxp = 0
        vz = 0
        avz = 0
        if good >> i & 1:
            x = (S[X_Q8UM + i] ^ s31) - s31
            kq = (P[_KQ + i] ^ s31) - s31
            e = x - ((S[XF_Q8UM + i] ^ s31) - s31)
            dx = (e >> 14) * alpha + ((e & 16383) * alpha + 8192 >> 14)
            if dx > dxmax:
                dx = dxmax
            elif dx < -dxmax:
                dx = -dxmax
            xf = (S[XF_Q8UM + i] ^ s31) - s31 + dx
            S[XF_Q8UM + i] = xf
            v = dx * fshz + 128 >> 8
            pl = (S[_PL_Q8 + i] ^ s31) - s31
            kp = ((pl >> 12) * kq >> ksh4) + ((pl & 4095) * kq >> ksh8)
            qt = 0
            if rth != 0:
                e = (S[_ACT + i] ^ s31) - s31
                if e <= rth:
                    qt = 256
                elif e < rth + rth:
                    qt = (rth + rth - e << 8) // rth
            a = az
            if mode > 0:
                if i != mode - 1:
                    t = (S[_XB_Q8UM + i] ^ s31) - s31 - ((S[_MOT + i] ^ s31) - s31)
                    if t > 67108864:
                        t = 67108864
                    elif t < -67108864:
                        t = -67108864
                    S[_XB_Q8UM + i] = t
                else:
                    a = 0
            e = xf - kp - ((S[_XB_Q8UM + i] ^ s31) - s31)
            w = (S[_WARM + i] ^ s31) - s31
            if w < warm:
                S[_WARM + i] = w + 1
                a = 16384 // (w + 1)
                if a < az:
                    a = az
            elif qt != 0:
                a = a * (256 - qt) >> 8
            t = (e & 16383) * a + ((S[_XBREM + i] ^ s31) - s31)
            inc = (e >> 14) * a + (t >> 14)
            S[_XBREM + i] = t & 16383
            S[_XB_Q8UM + i] += inc
            xh = kp + ((S[_XB_Q8UM + i] ^ s31) - s31)
            dxs = xh - ((S[_XH_Q8UM + i] ^ s31) - s31)
            S[_XH_Q8UM + i] = xh
            e = xf - xh - ((S[_E + i] ^ s31) - s31)
            S[_E + i] += (e >> 14) * ae + ((e & 16383) * ae + 8192 >> 14)
            if w < warm:
                dxs -= inc
            if dxs > dxmax:
                dxs = dxmax
            elif dxs < -dxmax:
                dxs = -dxmax
            xs = (S[XS_Q8UM + i] ^ s31) - s31 + dxs
            S[XS_Q8UM + i] = xs
            vz = dxs * fshz + 128 >> 8
            avz = vz
            if avz < 0:
                avz = -avz
            wp = play + ((rplay - play) * qt >> 8)
            if rth != 0:
                e = xs - ((S[_XL + i] ^ s31) - s31)
                t = (e & 16383) * al + ((S[_XLREM + i] ^ s31) - s31)
                S[_XL + i] += (e >> 14) * al + (t >> 14)
                S[_XLREM + i] = t & 16383
                e = xs - ((S[_XL + i] ^ s31) - s31)
                if e < 0:
                    e = -e
                if e > 16384:
                    e = 16384
                e = (e << 8) - ((S[_ACT + i] ^ s31) - s31)
                S[_ACT + i] += (e >> 14) * aa + ((e & 16383) * aa + 8192 >> 14)
            e = (S[XP_Q8UM + i] ^ s31) - s31
            if xs > e + wp:
                dxp = xs - wp - e
            elif xs < e - wp:
                dxp = xs + wp - e
            S[XP_Q8UM + i] = e + dxp
        S[DX_Q8UM + i] = dx
        S[V_UM_S + i] = v
        if (P[_KQ + i] ^ s31) - s31 != 0:
            v = vz
        av = v
        if v < 0:
            av = -v
        b = _VBP + i * nv
        if av >= (P[b + nv - 1] ^ s31) - s31:
            j = nv - 2
            fr = 1024
        else:
            j = 0
            while av >= (P[b + j + 1] ^ s31) - s31:
                j += 1
            fr = (av - ((P[b + j] ^ s31) - s31) << 10) // ((P[b + j + 1] ^ s31) - s31 - ((P[b + j] ^ s31) - s31))
        r = oforce + (i * nt + row) * nv + j
        f0 = (P[r] ^ s31) - s31 + (((P[r + 1] ^ s31) - s31 - ((P[r] ^ s31) - s31)) * fr + 512 >> 10)
        if tw != 0:
            r += nv
            f1 = (P[r] ^ s31) - s31 + (((P[r + 1] ^ s31) - s31 - ((P[r] ^ s31) - s31)) * fr + 512 >> 10)
            f0 += (f1 - f0) * tw + 512 >> 10
        if v < 0:
            f0 = -f0
        S[LOSS_N + i] = f0
        p = (S[P_KPA16 + i] ^ s31) - s31 >> 4
        if p < 0:
            p = 0
        elif p > pmax:
            p = pmax
        fs = (P[_FS0] ^ s31) - s31 + (p * ((P[_FSM] ^ s31) - s31) >> (P[_FSS] ^ s31) - s31)
        fc = (P[_FC0] ^ s31) - s31 + (p * ((P[_FCM] ^ s31) - s31) >> (P[_FCS] ^ s31) - s31)
        vs = (P[_VS0] ^ s31) - s31 + (p * ((P[_VSM] ^ s31) - s31) >> (P[_VSS] ^ s31) - s31)
        s2 = (P[_S20] ^ s31) - s31 + (p * ((P[_S2M] ^ s31) - s31) >> (P[_S2S] ^ s31) - s31)
        u = (avz << 9) // vs
        eq = 0
        if u < 2048:
            k = _GEXP + (u >> 4)
            eq = (P[k] ^ s31) - s31 + (((P[k + 1] ^ s31) - s31 - ((P[k] ^ s31) - s31)) * (u & 15) + 8 >> 4)
        g = (fc << 4) + ((fs - fc) * eq + 512 >> 10)
        S[G + i] = g
        wf = dxs * s0m + ((S[_WREM + i] ^ s31) - s31)
        w = wf >> s0s
        S[_WREM + i] = wf - (w << s0s)
        z = (S[ZF + i] ^ s31) - s31
        zn = z + w
        if dxp < 0:
            dxp = -dxp
        aw = dxp * s0m + s0h >> s0s
        if aw != 0 and zn != 0:
            ea = zn
            if zn < 0:
                ea = -zn
            dd = g + aw
            q = ea * (aw >> 10)
            q1 = q // dd
            q = q - q1 * dd << 10
            q2 = q // dd
            r2 = q - q2 * dd
            q = ea * (aw & 1023)
            q3 = q // dd
            r3 = q - q3 * dd
            q = (q1 << 10) + q2 + q3 + (r2 + r3 + (dd >> 1)) // dd
            if zn > 0:
                zn -= q
            else:
                zn += q
        if zn > g:
            zn = g
        elif zn < -g:
            zn = -g
        S[ZF + i] = zn
        d = zn - z
        f = zn + ((d >> 10) * c1m + ((d & 1023) * c1m >> 10) + c1half >> c1s10)
        f += (v >> 9) * s2 + ((v & 511) * s2 >> 9) + s2half >> s2s9
        S[FRIC_Q4 + i] = f
        if hp != 0 and good >> i & 1:
            xf = (S[XF_Q8UM + i] ^ s31) - s31
            e = (S[_XPM + i] ^ s31) - s31
            t = 0
            if xf > e + hp:
                t = xf - hp - e
            elif xf < e - hp:
                t = xf + hp - e
            S[_XPM + i] = e + t
            wf = dx * s0m + ((S[_WREMM + i] ^ s31) - s31)
            w = wf >> s0s
            S[_WREMM + i] = wf - (w << s0s)
            z = (S[ZM + i] ^ s31) - s31
            zm = z + w
            if t < 0:
                t = -t
            aw = t * s0m + s0h >> s0s
            if aw != 0 and zm != 0:
                ea = zm
                if zm < 0:
                    ea = -zm
                dd = g + aw
                q = ea * (aw >> 10)
                q1 = q // dd
                q = q - q1 * dd << 10
                q2 = q // dd
                r2 = q - q2 * dd
                q = ea * (aw & 1023)
                q3 = q // dd
                r3 = q - q3 * dd
                q = (q1 << 10) + q2 + q3 + (r2 + r3 + (dd >> 1)) // dd
                if zm > 0:
                    zm -= q
                else:
                    zm += q
            if zm > g:
                zm = g
            elif zm < -g:
                zm = -g
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
                if e > g >> 3:
                    S[_WHELD] |= 1 << i
        fn = f + 8 >> 4
        S[FRIC_N + i] = fn
        t = (S[RAW_N + i] ^ s31) - s31 + f0 + fn
        if t > 524287:
            t = 524287
        elif t < -524287:
            t = -524287
        S[TENSION_N + i] = t
        if good >> i & 1:
            S[SUM_N + i] += t
            S[SUM_KPA + i] += (S[P_KPA16 + i] ^ s31) - s31 >> 4
            S[COUNT + i] += 1
            if t < (S[MIN_N + i] ^ s31) - s31:
                S[MIN_N + i] = t
            if t > (S[MAX_N + i] ^ s31) - s31:
                S[MAX_N + i] = t
    if allw == 0:
        S[_SMODE] = 0
        S[_SSGN] = 0
        S[_SCNT] = 0
        S[_CL] = 0
    else:
        e = cv - ((S[_CL] ^ s31) - s31)
        c = (S[_CL] ^ s31) - s31 + (e >> 14) * ae + ((e & 16383) * ae + 8192 >> 14)
        S[_CL] = c
        s = -1
        if c > 0:
            s = 1
        sg = (S[_SSGN] ^ s31) - s31
        th = (P[_STH] ^ s31) - s31
        re = 0
        if mode == 0:
            lo = (P[_SLO] ^ s31) - s31
            hi = (P[_SSPAN] ^ s31) - s31
            for i in range(n):
                t = (S[_E + i] ^ s31) - s31
                c = t
                if t < 0:
                    c = -t
                if c << 2 > th:
                    d = c - lo
                    c = (c << 2) - th + ((S[_TOREM + i] ^ s31) - s31)
                    S[_TOREM + i] = c & 255
                    c = c >> 8
                    r = 0
                    if hi != 0 and d > 0:
                        if d >= hi:
                            r = c
                        else:
                            r = c * (((d << 8) + (hi >> 1)) // hi) + ((S[_TRREM + i] ^ s31) - s31)
                            S[_TRREM + i] = r & 255
                            r = r >> 8
                    if t < 0:
                        c = -c
                        r = -r
                    S[_XB_Q8UM + i] += c
                    S[_XH_Q8UM + i] += c - r
                    S[_E + i] = t - c
            c = (S[_CL] ^ s31) - s31
            if c < 0:
                c = -c
            if c > (P[_SVMIN] ^ s31) - s31 and s != sg:
                S[_SSGN] = s
                S[_SCNT] = 0
            elif (S[_SCNT] ^ s31) - s31 < (P[_SSET] ^ s31) - s31:
                S[_SCNT] += 1
            if c > (P[_SVMIN] ^ s31) - s31 and (S[_SCNT] ^ s31) - s31 >= (P[_SSET] ^ s31) - s31:
                best = 0
                for i in range(n):
                    if ((S[_E + i] ^ s31) - s31) * s > th:
                        if best == 0:
                            best = i + 1
                        else:
                            best = -1
                if best > 0:
                    S[_SMODE] = best
                    re = 1
                    so = 0
                    for i in range(n):
                        if i != best - 1:
                            so += (P[_AREA + i] ^ s31) - s31
                    if so > 0:
                        r = ((P[_AREA + best - 1] ^ s31) - s31 << 8) // so
                        t = (S[_E + best - 1] ^ s31) - s31
                        lead = (t >> 8) * r + ((t & 255) * r >> 8)
                        c = (S[_CL] ^ s31) - s31
                        if c > 33554432:
                            c = 33554432
                        elif c < -33554432:
                            c = -33554432
                        t = (c << 4) // (so + ((P[_AREA + best - 1] ^ s31) - s31))
                        if t > 65535:
                            t = 65535
                        elif t < -65535:
                            t = -65535
                        t = -lead - t * (16384 - ae) // (ae << 4)
                        for i in range(n):
                            if i != best - 1:
                                S[_E + i] = t
        else:
            if s != sg:
                re = 1
                S[_SCNT] = 0
            for i in range(n):
                if i != mode - 1 and ((S[_E + i] ^ s31) - s31) * sg > th:
                    re = 1
            if re != 0:
                S[_SMODE] = 0
                S[_SSGN] = s
        if re != 0:
            for i in range(n):
                t = (S[_E + i] ^ s31) - s31
                S[_XB_Q8UM + i] += t
                S[_XH_Q8UM + i] += t
                S[_E + i] = 0
    c = rec[rb + 2]
    prev = (S[_PREV_COUNT] ^ s31) - s31
    S[_PREV_COUNT] = c
    if prev >= 0:
        d = c - prev & 65535
        if d >= 32768:
            d -= 65536
        maxp = (P[_MAXP] ^ s31) - s31
        if d > maxp or d < -maxp:
            S[SHAFT_FAULT] = 1
        elif d != 0:
            t = d * ((P[_MMPP] ^ s31) - s31)
            S[WIN_Q16] += t
            if d > 0:
                S[WIN_PULSES] += d
            else:
                S[WIN_PULSES] -= d
            f = (S[_FRAC] ^ s31) - s31 + t
            S[DEPTH_MM] += f >> 16
            S[_FRAC] = f & 65535
    c = rec[rb + 3] & 3
    if c != 0 and (S[_PREV_HALL] ^ s31) - s31 == 0:
        S[MARKS_SEEN] += 1
        if (S[WIN_PULSES] ^ s31) - s31 == 0 and (S[LAST_WIN_PULSES] ^ s31) - s31 == 0:
            S[SHAFT_FAULT] = 1
        dep = (S[DEPTH_MM] ^ s31) - s31
        best = -1
        bd = (P[_SNAP] ^ s31) - s31 + 1
        m = (P[_OMARKS] ^ s31) - s31
        for j in range((P[_NMARKS] ^ s31) - s31):
            d = (P[m + j] ^ s31) - s31 - dep
            if d < 0:
                d = -d
            if d < bd:
                bd = d
                best = j
        if best >= 0:
            S[DEPTH_MM] = (P[m + best] ^ s31) - s31
            S[_FRAC] = 0
    S[_PREV_HALL] = c
    c = (S[SUB] ^ s31) - s31 + 1
    if c >= fshz:
        c = 0
        S[SEC] += 1
    S[SUB] = c
    c = (S[IN_WINDOW] ^ s31) - s31 + 1
    if c < (P[_WIN] ^ s31) - s31:
        S[IN_WINDOW] = c
        return 0
    S[IN_WINDOW] = 0
    tot = 0
    used = 0
    for i in range(n):
        o = OUT_ROPES + 4 * i
        c = (S[COUNT + i] ^ s31) - s31
        if c == 0:
            S[o] = TENSION_ABSENT
            S[o + 1] = TENSION_ABSENT
            S[o + 2] = TENSION_ABSENT
            S[o + 3] = RAW_KPA_ABSENT
        else:
            for j in range(3):
                if j == 0:
                    t = ((S[SUM_N + i] ^ s31) - s31 + 5 * c) // (10 * c)
                elif j == 1:
                    t = ((S[MIN_N + i] ^ s31) - s31 + 5) // 10
                else:
                    t = ((S[MAX_N + i] ^ s31) - s31 + 5) // 10
                if t > 32767:
                    t = 32767
                elif t < -32767:
                    t = -32767
                S[o + j] = t
            tot += (S[o] ^ s31) - s31
            used += 1
            p = ((S[SUM_KPA + i] ^ s31) - s31 + (c >> 1)) // c
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
        c = (S[_XCNT + i] ^ s31) - s31
        t = POS_ABSENT
        if c != 0:
            t = ((S[_XSUM + i] ^ s31) - s31 + 50 * c) // (100 * c)
            if t > 32767:
                t = 32767
            elif t < -32767:
                t = -32767
        S[OUT_POS + i] = t
        S[_XSUM + i] = 0
        S[_XCNT + i] = 0
    flags = 0
    if used > 1 and tot > 0:
        lim = (P[_IMB] ^ s31) - s31
        for i in range(n):
            m = (S[OUT_ROPES + 4 * i] ^ s31) - s31
            if m != TENSION_ABSENT:
                d = m * used - tot
                if d < 0:
                    d = -d
                if d * 1000 > lim * tot:
                    flags |= FLAG_IMBALANCE
    c = (P[_BSH] ^ s31) - s31
    t = ((S[BATT_SUM] ^ s31) - s31) // ((P[_WIN] ^ s31) - s31) * ((P[_BMUL] ^ s31) - s31) + (1 << c >> 1) >> c
    if t < (P[_BLOW] ^ s31) - s31:
        flags |= FLAG_BATTERY_LOW
    if t > 65535:
        t = 65535
    S[OUT_BATT_MV] = t
    S[BATT_SUM] = 0
    if (S[SHAFT_FAULT] ^ s31) - s31 != 0:
        flags |= FLAG_SPEED_FAULT
        S[SHAFT_FAULT] = 0
    t = ((S[WIN_Q16] ^ s31) - s31 >> 10) * ((P[_FRHZ] ^ s31) - s31) >> 6
    if t > 32767:
        t = 32767
    elif t < -32767:
        t = -32767
    S[OUT_SPEED] = t
    S[WIN_Q16] = 0
    S[LAST_WIN_PULSES] = (S[WIN_PULSES] ^ s31) - s31
    S[WIN_PULSES] = 0
    S[OUT_FLAGS] = flags
    S[OUT_FAULTS] = (S[WFAULTS] ^ s31) - s31
    S[WFAULTS] = 0
    S[OUT_STROKE] = (S[_WSTROKE] ^ s31) - s31
    S[_WSTROKE] = 0
    S[OUT_HELD] = (S[_WHELD] ^ s31) - s31
    S[_WHELD] = 0
    S[OUT_TEMP_CC] = (S[TEMP_CC] ^ s31) - s31
    S[OUT_SEC] = (S[SEC] ^ s31) - s31
    S[OUT_SUB] = (S[SUB] ^ s31) - s31
    S[OUT_DEPTH_MM] = (S[DEPTH_MM] ^ s31) - s31
    return 1
