"""The node config (/node.json, schema 1): canonical form, CRC check, validation.

`parse(doc)` checks the schema version, the CRC over `canonical(doc["node"])`
and the presence, type and range of every field of the integer `node` section,
and returns a `Config`; a bad file raises `ConfigError(field, reason)` naming
the field. The host builds the section (`ropemon.nodeconfig`) and uses
`canonical` from here, so both sides hash the same bytes. Runs at boot only:
allocation is fine here, never in the sample path.
"""
import array

from ropenode.crc16 import crc16

SCHEMA = 1
_I30 = 1 << 30
GEXP_POINTS = 129    # exp(-u^2) at u = k/32, k = 0..128 (Q14); 0 beyond u = 4
MAX_LOSS_POINTS = 32
MAX_LOSS_TEMPS = 8
MAX_MARKS = 64
TENSION_MAX_N = 1 << 19  # |T| bound the builder proves; window sums stay below 2**30


class ConfigError(Exception):
    """A config the node refuses: `field` is a dotted path, `reason` says why."""

    def __init__(self, field, reason):
        super().__init__("%s: %s" % (field, reason))
        self.field = field
        self.reason = reason


def _canon(obj, out, path):
    t = type(obj)
    if t is dict:
        out.append(b"{")
        first = True
        for k in sorted(obj):
            if type(k) is not str:
                raise ConfigError(path, "keys must be strings")
            if not first:
                out.append(b",")
            first = False
            out.append(b'"' + k.encode() + b'":')
            _canon(obj[k], out, path + "." + k if path else k)
        out.append(b"}")
    elif t is list or t is tuple:
        out.append(b"[")
        for i, v in enumerate(obj):
            if i:
                out.append(b",")
            _canon(v, out, "%s[%d]" % (path, i))
        out.append(b"]")
    elif t is int:
        out.append(str(obj).encode())
    else:
        raise ConfigError(path, "only ints, lists and dicts allowed, got %s" % t.__name__)


def canonical(obj):
    """The canonical bytes of an int-only JSON value: keys sorted, no spaces.

    Equal to CPython's json.dumps(obj, sort_keys=True, separators=(",", ":"))
    for such values; floats, bools, strings and null are refused.
    """
    out = []
    _canon(obj, out, "node")
    return b"".join(out)


def _get(d, key, path):
    if type(d) is not dict:
        raise ConfigError(path, "must be an object")
    if key not in d:
        raise ConfigError(path + "." + key if path else key, "missing")
    return d[key]


def _int(d, key, path, lo, hi):
    f = path + "." + key if path else key
    v = _get(d, key, path)
    if type(v) is not int:
        raise ConfigError(f, "must be an integer, got %s" % type(v).__name__)
    if v < lo or v > hi:
        raise ConfigError(f, "%d out of range %d..%d" % (v, lo, hi))
    return v


def _list(d, key, path, n_lo, n_hi):
    f = path + "." + key if path else key
    v = _get(d, key, path)
    if type(v) is not list:
        raise ConfigError(f, "must be a list")
    if len(v) < n_lo or len(v) > n_hi:
        raise ConfigError(f, "length %d out of range %d..%d" % (len(v), n_lo, n_hi))
    return v


def _ints(d, key, path, n_lo, n_hi, lo, hi, ascending=False):
    f = path + "." + key if path else key
    v = _list(d, key, path, n_lo, n_hi)
    for i, x in enumerate(v):
        if type(x) is not int:
            raise ConfigError("%s[%d]" % (f, i), "must be an integer")
        if x < lo or x > hi:
            raise ConfigError("%s[%d]" % (f, i), "%d out of range %d..%d" % (x, lo, hi))
        if ascending and i and x <= v[i - 1]:
            raise ConfigError("%s[%d]" % (f, i), "must be strictly ascending")
    return v


def _linear(d, key, path, lo, hi):
    """A parameter linear in sensor pressure: at_0 + (p_kpa * slope_mul >> slope_shift)."""
    f = path + "." + key
    v = _get(d, key, path)
    at0 = _int(v, "at_0", f, lo, hi)
    mul = _int(v, "slope_mul", f, -(1 << 15), 1 << 15)
    sh = _int(v, "slope_shift", f, 0, 30)
    return at0, mul, sh


class Config:
    """A validated node section: plain ints and preallocated int arrays."""


def _arr(n):
    return array.array("i", [0] * n)


def parse(doc):
    """Validate a node.json document (dict); return a Config or raise ConfigError."""
    if type(doc) is not dict:
        raise ConfigError("document", "must be a JSON object")
    schema = _get(doc, "schema", "")
    if type(schema) is not int or schema != SCHEMA:
        raise ConfigError("schema", "unknown schema %r (this node reads %d)" % (schema, SCHEMA))
    node = _get(doc, "node", "")
    if type(node) is not dict:
        raise ConfigError("node", "must be an object")
    crc = _get(doc, "crc", "")
    if type(crc) is not int:
        raise ConfigError("crc", "must be an integer")
    got = crc16(canonical(node))
    if got != crc:
        raise ConfigError("crc", "mismatch: file says %d, node section hashes to %d" % (crc, got))
    return parse_node(node)


def parse_node(nd):
    """Validate the integer node section alone (the CRC is checked by `parse`)."""
    c = Config()
    P = "node"
    c.node_id = _int(nd, "node_id", P, 0, 255)
    c.key = bytes(_ints(nd, "key", P, 16, 32, 0, 255))
    n = c.ropes = _int(nd, "ropes", P, 1, 4)
    c.sample_hz = _int(nd, "sample_hz", P, 1, 1000)
    c.frame_hz = _int(nd, "frame_hz", P, 1, c.sample_hz)
    if c.sample_hz % c.frame_hz:
        raise ConfigError("node.frame_hz", "sample_hz %d is not a multiple of it" % c.sample_hz)
    c.window = c.sample_hz // c.frame_hz
    c.rated_rope_tension_n = _int(nd, "rated_rope_tension_n", P, 1, TENSION_MAX_N)
    c.imbalance_permille = _int(nd, "imbalance_permille", P, 0, 1000)
    c.battery_low_mv = _int(nd, "battery_low_mv", P, 0, 65535)
    c.battery_mv_mul = _int(nd, "battery_mv_mul", P, 0, _I30 // 65536)
    c.battery_mv_shift = _int(nd, "battery_mv_shift", P, 0, 30)

    pr = _list(nd, "pressure", P, n, n)
    names = ("counts_4ma", "fault_lo_counts", "fault_hi_counts", "kpa_at_4ma", "kpa_mul",
             "kpa_shift", "tension_n_at_4ma", "tension_n_mul", "tension_n_shift")
    c.pressure = _arr(9 * n)  # per rope, the 9 ints in `names` order
    for i in range(n):
        path = "node.pressure[%d]" % i
        e = pr[i]
        c4 = _int(e, "counts_4ma", path, 0, 65535)
        lo = _int(e, "fault_lo_counts", path, 0, c4)
        hi = _int(e, "fault_hi_counts", path, c4 + 1, 65535)
        vals = (c4, lo, hi,
                _int(e, "kpa_at_4ma", path, -100000, 100000),
                _int(e, "kpa_mul", path, 0, _I30 // 65536),
                _int(e, "kpa_shift", path, 0, 30),
                _int(e, "tension_n_at_4ma", path, -TENSION_MAX_N, TENSION_MAX_N),
                _int(e, "tension_n_mul", path, 0, _I30 // 65536),
                _int(e, "tension_n_shift", path, 0, 30))
        for j in range(9):
            c.pressure[9 * i + j] = vals[j]
    c.p_kpa_max = _int(nd, "p_kpa_max", P, 1, 100000)

    dp = _list(nd, "displacement", P, n, n)
    c.displacement = _arr(6 * n)
    for i in range(n):
        path = "node.displacement[%d]" % i
        e = dp[i]
        clo = _int(e, "counts_lo", path, 0, 65535)
        vals = (clo,
                _int(e, "fault_lo_counts", path, 0, clo),
                _int(e, "fault_hi_counts", path, clo + 1, 65535),
                _int(e, "q8um_at_lo", path, -(1 << 26), 1 << 26),
                _int(e, "q8um_mul", path, 0, _I30 // 65536),
                _int(e, "q8um_shift", path, 0, 30))
        for j in range(6):
            c.displacement[6 * i + j] = vals[j]

    ve = _get(nd, "velocity", P)
    c.alpha_q14 = _int(ve, "alpha_q14", "node.velocity", 1, 16384)
    c.dx_max_q8um = _int(ve, "dx_max_q8um", "node.velocity", 1, (1 << 30) // 1000 // 4)
    if c.dx_max_q8um * c.sample_hz >= 1 << 28:
        raise ConfigError("node.velocity.dx_max_q8um", "times sample_hz exceeds 2**28")

    fr = _get(nd, "friction", P)
    FP = "node.friction"
    c.sigma0_mul = _int(fr, "sigma0_mul", FP, 0, _I30 >> 19)
    c.sigma0_shift = _int(fr, "sigma0_shift", FP, 0, 30)
    if (c.dx_max_q8um * c.sigma0_mul) >> c.sigma0_shift >= 1 << 19:
        raise ConfigError("node.friction.sigma0_mul", "sigma0 * dx_max beyond 2**19 (32 kN)")
    c.c1_mul = _int(fr, "c1_mul", FP, 0, (1 << 19) - 1)
    c.c1_shift = _int(fr, "c1_shift", FP, 10, 30)
    c.fs = _linear(fr, "fs_n", FP, 1, 32767)
    c.fc = _linear(fr, "fc_n", FP, 1, 32767)
    c.vs = _linear(fr, "vs_um_s", FP, 1, 1 << 20)
    c.s2 = _linear(fr, "sigma2_q", FP, 0, (1 << 18) - 1)
    c.sigma2_shift = _int(fr, "sigma2_shift", FP, 9, 30)
    c.gexp_q14 = array.array("i", _ints(fr, "gexp_q14", FP, GEXP_POINTS, GEXP_POINTS, 0, 16384))
    if c.gexp_q14[GEXP_POINTS - 1] != 0:
        raise ConfigError("node.friction.gexp_q14[%d]" % (GEXP_POINTS - 1), "must be 0 (table end)")
    # The parameters at the pressure extremes must stay in range (they are linear).
    for name, (at0, mul, sh), lo, hi in (("fs_n", c.fs, 64, 32767), ("fc_n", c.fc, 64, 32767),
                                         ("vs_um_s", c.vs, 10, 1 << 20),
                                         ("sigma2_q", c.s2, 0, (1 << 18) - 1)):
        for p in (0, c.p_kpa_max):
            v = at0 + ((p * mul) >> sh)
            if v < lo or v > hi:
                raise ConfigError(FP + "." + name, "%d at %d kPa out of range %d..%d" % (v, p, lo, hi))
    for p in (0, c.p_kpa_max):
        fs = c.fs[0] + ((p * c.fs[1]) >> c.fs[2])
        fc = c.fc[0] + ((p * c.fc[1]) >> c.fc[2])
        if fc > fs:
            raise ConfigError("node.friction.fc_n", "Fc above Fs at %d kPa" % p)

    lo_ = _get(nd, "loss", P)
    LP = "node.loss"
    temps = _ints(lo_, "temps_cc", LP, 1, MAX_LOSS_TEMPS, -5000, 15000, ascending=True)
    c.loss_nt = len(temps)
    c.loss_temps_cc = array.array("i", temps)
    vrows = _list(lo_, "v_um_s", LP, n, n)
    nv = -1
    c.loss_v = None
    for i in range(n):
        f = "%s.v_um_s[%d]" % (LP, i)
        if type(vrows[i]) is not list:
            raise ConfigError(f, "must be a list")
        row = _ints({"r": vrows[i]}, "r", "", 2, MAX_LOSS_POINTS, 0, 1 << 19, ascending=True)
        if row[0] != 0:
            raise ConfigError(f + "[0]", "must be 0 (zero flow)")
        if nv < 0:
            nv = len(row)
            c.loss_v = _arr(n * nv)
        elif len(row) != nv:
            raise ConfigError(f, "length %d differs from rope 0's %d" % (len(row), nv))
        for j in range(nv):
            c.loss_v[i * nv + j] = row[j]
    c.loss_nv = nv
    frows = _list(lo_, "force_n", LP, n, n)
    c.loss_force_n = _arr(n * c.loss_nt * nv)
    for i in range(n):
        f = "%s.force_n[%d]" % (LP, i)
        if type(frows[i]) is not list or len(frows[i]) != c.loss_nt:
            raise ConfigError(f, "must be a list of %d rows (one per temperature)" % c.loss_nt)
        for t in range(c.loss_nt):
            ft = "%s[%d]" % (f, t)
            if type(frows[i][t]) is not list or len(frows[i][t]) != nv:
                raise ConfigError(ft, "must be a list of %d ints (one per flow point)" % nv)
            row = _ints({"r": frows[i][t]}, "r", "", nv, nv, -(1 << 16), 1 << 16)
            if row[0] != 0:
                raise ConfigError(ft + "[0]", "must be 0 (no loss at zero flow)")
            for j in range(nv):
                c.loss_force_n[(i * c.loss_nt + t) * nv + j] = row[j]

    te = _get(nd, "temperature", P)
    TP = "node.temperature"
    c.temp_fitted = _int(te, "fitted", TP, 0, 1)
    c.temp_counts_at_0c = _int(te, "counts_at_0c", TP, 0, 65535)
    c.temp_cc_mul = _int(te, "cc_mul", TP, -(_I30 // 65536), _I30 // 65536)
    c.temp_cc_shift = _int(te, "cc_shift", TP, 0, 30)
    c.temp_fault_lo = _int(te, "fault_lo_counts", TP, 0, 65535)
    c.temp_fault_hi = _int(te, "fault_hi_counts", TP, c.temp_fault_lo, 65535)
    c.oil_temp_assumed_cc = _int(te, "assumed_cc", TP, -5000, 15000)

    sh = _get(nd, "shaft", P)
    SP = "node.shaft"
    c.mm_per_pulse_q16 = _int(sh, "mm_per_pulse_q16", SP, 1, 1 << 22)
    c.max_pulses_per_sample = _int(sh, "max_pulses_per_sample", SP, 1, 32767)
    if c.max_pulses_per_sample * c.mm_per_pulse_q16 >= 1 << 28:
        raise ConfigError("node.shaft.max_pulses_per_sample", "times mm_per_pulse_q16 exceeds 2**28")
    if c.max_pulses_per_sample * c.mm_per_pulse_q16 * c.window >= 1 << 29:
        raise ConfigError("node.shaft.max_pulses_per_sample", "a frame window's travel exceeds 2**29")
    c.marks_mm = array.array("i", _ints(sh, "marks_mm", SP, 0, MAX_MARKS, -100000, 5000000,
                                        ascending=True))
    c.snap_mm = _int(sh, "snap_mm", SP, 0, 100000)
    c.start_depth_mm = _int(sh, "start_depth_mm", SP, -100000, 5000000)

    # Window sums must stay small ints: the largest tension times the window.
    if c.window * TENSION_MAX_N >= _I30:
        raise ConfigError("node.frame_hz", "window of %d samples too long for the tension sums" % c.window)
    return c


def load(path="/node.json"):
    """Read and parse a node.json from flash; raise OSError, ValueError or ConfigError."""
    import json
    with open(path) as f:
        doc = json.load(f)
    return parse(doc)
