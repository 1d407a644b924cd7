"""The node config (/node.json, schema 1): canonical form, CRC check, validation.

`parse(doc)` checks the schema version, the CRC over `canonical(doc["node"])`
(`canonical_crc16`: the CRC without the bytes)
and the presence, type and range of every field of the integer `node` section,
and returns a `Config`; a bad file raises `ConfigError(field, reason)` naming
the field. A HAL boots with `load_for_boot`, which never raises and, for a
refused file, still gives the node identity to sign config-fault frames with.
The host builds the section (`ropemon.nodejson`) and uses `canonical` from
here, so both sides hash the same bytes. Runs at boot only: allocation is fine
here, never in the sample path. Validation is driven by the tables below (less
code resident on the node than one call per field).
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

# The int fields, one per line: [section.]key lo hi (section of "node"); each
# becomes the Config attribute `key`. A string costs less resident heap than tuples.
_FIELDS = """
node_id 0 255
ropes 1 4
sample_hz 1 1000
frame_hz 1 1000
rated_rope_tension_n 1 524288
imbalance_permille 0 1000
battery_low_mv 0 65535
battery_mv_mul 0 16384
battery_mv_shift 0 29
p_kpa_max 1 100000
velocity.alpha_q14 1 16384
velocity.dx_max_q8um 1 268435
friction.sigma0_mul 0 2048
friction.sigma0_shift 0 29
friction.c1_mul 0 524287
friction.c1_shift 10 30
friction.sigma2_shift 9 30
friction.alpha_z_q14 1 16384
friction.tracker_a1_q14 0 32767
friction.tracker_a2_q14 0 16383
friction.tracker_v_shift 0 12
friction.tracker_b_shift 0 5
friction.compliance_shift 5 30
friction.warmup_samples 0 65535
friction.alpha_e_q14 1 4096
friction.stroke_q8um 0 32768
friction.stroke_vmin_q16 0 536870912
friction.stroke_settle 0 65535
friction.alpha_l_q14 1 16384
friction.alpha_a_q14 1 16384
friction.noise_ref_q6 0 262144
friction.noise_shift 0 16
friction.slide_lo_q8um 0 16777216
friction.slide_span_q8um 0 1048576
friction.hold_play_q8um 0 16777216
step_recover 1 65535
temperature.fitted 0 1
temperature.counts_at_0c 0 65535
temperature.cc_mul -16384 16384
temperature.cc_shift 0 30
temperature.fault_lo_counts 0 65535
temperature.fault_hi_counts 0 65535
temperature.assumed_cc -5000 15000
shaft.mm_per_pulse_q16 1 4194304
shaft.max_pulses_per_sample 1 32767
shaft.snap_mm 0 100000
shaft.start_depth_mm -100000 5000000
"""
# Per-rope channel entries, stored in this order (10 and 6 ints per rope); the
# 2nd and 3rd (fault limits) must bracket the 1st (4 mA / lowest counts).
# step_max_counts: a larger step between two readings is implausible (0: not checked).
# Multipliers of a 16-bit count stay <= 2**14 so products stay below 2**30.
_PRESSURE = """
counts_4ma 0 65535
fault_lo_counts 0 65535
fault_hi_counts 0 65535
kpa_at_4ma -100000 100000
kpa_mul 0 16384
kpa_shift 4 30
tension_n_at_4ma -524288 524288
tension_n_mul 0 16384
tension_n_shift 0 30
step_max_counts 0 65535
"""
_DISPLACEMENT = """
counts_lo 0 65535
fault_lo_counts 0 65535
fault_hi_counts 0 65535
q8um_at_lo -67108864 67108864
q8um_mul 0 16384
q8um_shift 0 30
"""
# The piston's travel and stroke margin per rope, um/256 from mid-stroke (the displacement
# calibration's zero), in the order the kernel keeps them after each rope's 6 displacement
# ints: a reading below travel_lo or above travel_hi is a displacement fault; a position at or
# below stroke_lo / at or above stroke_hi sets the rope's stroke bit. Each key is optional (an
# older node.json): its default here is beyond any position (the check is off). An int applies
# to every rope, else a list of one per rope.
_LIMIT = 1 << 29
_STROKE = (("travel_lo_q8um", -_LIMIT), ("stroke_lo_q8um", -_LIMIT), ("stroke_hi_q8um", _LIMIT),
           ("travel_hi_q8um", _LIMIT))
# A position the node holds: below this in size at both fault limits of its channel (um/256,
# 131 mm), so a stroke or travel limit at +-this is never reached.
POSITION_MAX_Q8UM = 1 << 25
# Friction parameters linear in sensor pressure, {at_0, slope_mul, slope_shift}:
# key, lo and hi of at_0, lo over 0..p_kpa_max; each becomes the attribute `key` = (at0, mul, shift).
_LINEAR = """
fs_n 1 32767 64
fc_n 1 32767 64
vs_um_s 1 1048576 10
sigma2_q 0 262143 0
"""


def _table(text):
    """Rows of a table above: [name, int, int, ...]."""
    rows = []
    for line in text.split("\n"):
        if line:
            w = line.split()
            rows.append([w[0]] + [int(x) for x in w[1:]])
    return rows


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


def _crc_of(obj, crc):
    """crc16 continued over canonical(obj) without building it (the bytes and the paths
    `canonical` builds, held all at once, more than double the heap a boot needs); None
    for a value `canonical` refuses (it then names the field)."""
    t = type(obj)
    if t is int:
        return crc16(b"%d" % obj, -1, crc)
    if t is dict:
        crc = crc16(b"{", -1, crc)
        first = True
        for k in sorted(obj):
            if type(k) is not str:
                return None
            if not first:
                crc = crc16(b",", -1, crc)
            first = False
            crc = crc16(b'"', -1, crc)
            crc = crc16(k.encode(), -1, crc)
            crc = _crc_of(obj[k], crc16(b'":', -1, crc))
            if crc is None:
                return None
        return crc16(b"}", -1, crc)
    if t is list or t is tuple:
        crc = crc16(b"[", -1, crc)
        for i in range(len(obj)):
            if i:
                crc = crc16(b",", -1, crc)
            crc = _crc_of(obj[i], crc)
            if crc is None:
                return None
        return crc16(b"]", -1, crc)
    return None


def canonical_crc16(obj):
    """crc16(canonical(obj)), with far less heap; ConfigError as `canonical` for a value it
    refuses."""
    crc = _crc_of(obj, 0xFFFF)
    if crc is None:
        canonical(obj)  # raises, naming the field
        raise ConfigError("node", "not canonical")
    return crc


def canonical(obj):
    """The canonical bytes of an int-only JSON value: keys sorted, no spaces.

    Equal to CPython's json.dumps(obj, sort_keys=True, separators=(",", ":"))
    for such values; floats, bools, strings and null are refused.
    """
    out = []
    _canon(obj, out, "node")
    return b"".join(out)


def _range(f, v, lo, hi):
    if v < lo or v > hi:
        raise ConfigError(f, "%d out of range %d..%d" % (v, lo, hi))


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
    _range(f, v, lo, hi)
    return v


def _ints(d, key, path, n_lo, n_hi, lo, hi, ascending=False):
    """d[key]: a list of n_lo..n_hi ints in lo..hi, as array('i'); an int key indexes a list."""
    if type(key) is int:
        f = "%s[%d]" % (path, key)
        v = d[key]
    else:
        f = path + "." + key
        v = _get(d, key, path)
    if type(v) is not list:
        raise ConfigError(f, "must be a list")
    if len(v) < n_lo or len(v) > n_hi:
        raise ConfigError(f, "length %d out of range %d..%d" % (len(v), n_lo, n_hi))
    for i, x in enumerate(v):
        if type(x) is not int:
            raise ConfigError("%s[%d]" % (f, i), "must be an integer")
        _range("%s[%d]" % (f, i), x, lo, hi)
        if ascending and i and x <= v[i - 1]:
            raise ConfigError("%s[%d]" % (f, i), "must be strictly ascending")
    return array.array("i", v)


def _channels(nd, key, n, spec):
    """Per-rope channel entries -> array('i') of len(spec) ints per rope."""
    k = len(spec)
    out = array.array("i", bytes(4 * k * n))
    rows = _get(nd, key, "node")
    if type(rows) is not list or len(rows) != n:
        raise ConfigError("node." + key, "must be a list of %d entries (one per rope)" % n)
    for i in range(n):
        path = "node.%s[%d]" % (key, i)
        for j in range(k):
            name, lo, hi = spec[j]
            out[k * i + j] = _int(rows[i], name, path, lo, hi)
        base = out[k * i]
        if out[k * i + 1] > base:
            _range(path + "." + spec[1][0], out[k * i + 1], 0, base)
        if out[k * i + 2] <= base:
            _range(path + "." + spec[2][0], out[k * i + 2], base + 1, 65535)
    return out


class Config:
    """A validated node section: the attributes named in the tables above, plus
    key (bytes), window, pressure and displacement (per-rope int arrays), the _STROKE keys
    (an int array of one per rope each),
    gexp_q14, temps_cc, loss_nt, loss_nv, v_um_s, force_n and marks_mm."""


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
    got = canonical_crc16(node)
    if got != crc:
        raise ConfigError("crc", "mismatch: file says %d, node section hashes to %d" % (crc, got))
    return parse_node(node)


def parse_node(nd):
    """Validate the integer node section alone (the CRC is checked by `parse`)."""
    c = Config()
    for key, lo, hi in _table(_FIELDS):
        d = nd
        path = "node"
        if "." in key:
            sec, key = key.split(".")
            d = _get(nd, sec, path)
            path += "." + sec
        setattr(c, key, _int(d, key, path, lo, hi))
    c.key = bytes(list(_ints(nd, "key", "node", 16, 32, 0, 255)))
    n = c.ropes
    _range("node.frame_hz", c.frame_hz, 1, c.sample_hz)
    if c.sample_hz % c.frame_hz:
        raise ConfigError("node.frame_hz", "sample_hz %d is not a multiple of it" % c.sample_hz)
    c.window = c.sample_hz // c.frame_hz
    # Window sums must stay small ints: the largest tension times the window.
    if c.window * TENSION_MAX_N >= _I30:
        raise ConfigError("node.frame_hz", "window of %d samples too long for the tension sums" % c.window)
    _range("node.temperature.fault_hi_counts", c.fault_hi_counts, c.fault_lo_counts, 65535)
    # battery mV = (mean counts * mul + half) >> shift: the mean of 16-bit counts, rounded
    if 65535 * c.battery_mv_mul + ((1 << c.battery_mv_shift) >> 1) >= _I30:
        raise ConfigError("node.battery_mv_mul", "times 65535 counts, rounded, beyond 2**30")
    c.pressure = _channels(nd, "pressure", n, _table(_PRESSURE))
    c.displacement = _channels(nd, "displacement", n, _table(_DISPLACEMENT))
    pc = c.pressure
    for i in range(n):
        b = 10 * i
        for j in (1, 2):  # the kPa at both fault limits bound every pressure the node holds
            # (kPa/16 with the same mul: no larger than 16 times this, < 2**21)
            _range("node.pressure[%d].kpa_mul" % i, pc[b + 3] + (((pc[b + j] - pc[b]) * pc[b + 4])
                                                               >> pc[b + 5]), -100000, 100000)
    dc = c.displacement
    for i in range(n):
        b = 6 * i
        for j in (1, 2):  # the positions at both fault limits bound every position the node holds
            _range("node.displacement[%d].q8um_mul" % i, dc[b + 3] + (((dc[b + j] - dc[b]) * dc[b + 4])
                                                                     >> dc[b + 5]),
                   1 - POSITION_MAX_Q8UM, POSITION_MAX_Q8UM - 1)
    for key, default in _STROKE:
        v = nd.get(key, default)
        if type(v) is int:
            _range("node." + key, v, -_LIMIT, _LIMIT)
            setattr(c, key, array.array("i", [v] * n))
        else:
            setattr(c, key, _ints(nd, key, "node", n, n, -_LIMIT, _LIMIT))
    for i in range(n):
        f = "node.%s[%d]"
        if c.travel_lo_q8um[i] > c.stroke_lo_q8um[i]:
            raise ConfigError(f % ("travel_lo_q8um", i), "above stroke_lo_q8um")
        if c.stroke_lo_q8um[i] >= c.stroke_hi_q8um[i]:
            raise ConfigError(f % ("stroke_lo_q8um", i), "not below stroke_hi_q8um")
        if c.stroke_hi_q8um[i] > c.travel_hi_q8um[i]:
            raise ConfigError(f % ("travel_hi_q8um", i), "below stroke_hi_q8um")
    if c.dx_max_q8um * c.sample_hz >= 1 << 28:
        raise ConfigError("node.velocity.dx_max_q8um", "times sample_hz exceeds 2**28")

    FP = "node.friction"
    fr = _get(nd, "friction", "node")
    if (c.dx_max_q8um * c.sigma0_mul) >> c.sigma0_shift >= 1 << 19:
        raise ConfigError(FP + ".sigma0_mul", "sigma0 * dx_max beyond 2**19 (32 kN)")
    if c.hold_play_q8um > c.dx_max_q8um:  # a play wider than the largest step: a typo
        raise ConfigError(FP + ".hold_play_q8um", "wider than dx_max_q8um")
    if c.dx_max_q8um * c.sigma0_mul + (1 << c.sigma0_shift) >= _I30:  # a step and its remainder
        raise ConfigError(FP + ".sigma0_mul", "times dx_max, with the remainder, beyond 2**30")
    for key, lo, hi, lo_p in _table(_LINEAR):
        f = FP + "." + key
        d = _get(fr, key, FP)
        at0 = _int(d, "at_0", f, lo, hi)
        mul = _int(d, "slope_mul", f, -(1 << 15), 1 << 15)
        sh = _int(d, "slope_shift", f, 0, 30)
        if c.p_kpa_max * (mul if mul > 0 else -mul) >= _I30:  # p * mul, the node's product
            raise ConfigError(f + ".slope_mul", "times p_kpa_max beyond 2**30")
        setattr(c, key, (at0, mul, sh))
        # linear in pressure: in range at both ends means in range throughout
        for p in (0, c.p_kpa_max):
            v = at0 + ((p * mul) >> sh)
            if v < lo_p or v > hi:
                raise ConfigError(f, "%d at %d kPa out of range %d..%d" % (v, p, lo_p, hi))
    for p in (0, c.p_kpa_max):
        if c.fc_n[0] + ((p * c.fc_n[1]) >> c.fc_n[2]) > c.fs_n[0] + ((p * c.fs_n[1]) >> c.fs_n[2]):
            raise ConfigError(FP + ".fc_n", "Fc above Fs at %d kPa" % p)
    c.compliance_q = _ints(fr, "compliance_q", FP, n, n, 0, (1 << 17) - 1)
    for i in range(n):  # k p at 100000 kPa stays a position (< 2**25 um/256)
        if (c.compliance_q[i] * 3125) >> (c.compliance_shift - 5) >= 1 << 25:
            raise ConfigError("%s.compliance_q[%d]" % (FP, i), "k times 100 MPa beyond 2**25 um/256")
    # cylinder area over the ropes' mean, Q8: the common motion stays below 2**29
    c.area_q8 = _ints(fr, "area_q8", FP, n, n, 128, 384)
    # the LuGre play half-width, um/256, when 1..n pressure channels are healthy; the rest
    # hold's play (at least as wide) and activity threshold (um/65536; 0: no rest hold)
    c.play_q8um = _ints(fr, "play_q8um", FP, n, n, 0, 1 << 24)
    c.rest_play_q8um = _ints(fr, "rest_play_q8um", FP, n, n, 0, 1 << 20)
    c.rest_q16um = _ints(fr, "rest_q16um", FP, n, n, 0, 1 << 21)
    for i in range(n):
        if c.rest_q16um[i] and c.rest_play_q8um[i] < c.play_q8um[i]:
            raise ConfigError("%s.rest_play_q8um[%d]" % (FP, i), "narrower than play_q8um")
        # noise following scales the threshold up to twice: the quiet's shift stays < 2**30
        if c.noise_ref_q6 and c.rest_q16um[i] >= 1 << 20:
            raise ConfigError("%s.rest_q16um[%d]" % (FP, i), "2**20 or more with noise following")
    # noise following (level in kPa/16, Q6; 0: the plays are fixed) needs its low-pass
    if (c.noise_ref_q6 == 0) != (c.noise_shift == 0):
        raise ConfigError(FP + ".noise_shift", "0 exactly when noise_ref_q6 is 0")
    # slide following (lo, span in um/256): a span of 0 is off, and then lo is 0 too
    if c.slide_span_q8um == 0 and c.slide_lo_q8um != 0:
        raise ConfigError(FP + ".slide_lo_q8um", "must be 0 when slide_span_q8um is 0 (off)")
    # the pressure tracker's Kalman gains: of c (Q14), v (Q(14 + tracker_v_shift)), b0, b1
    # (Q(14 + tracker_b_shift))
    c.tracker_k_q14 = _ints(fr, "tracker_k_q14", FP, 4, 4, -16384, 16384)
    c.gexp_q14 = _ints(fr, "gexp_q14", FP, GEXP_POINTS, GEXP_POINTS, 0, 16384)
    if c.gexp_q14[GEXP_POINTS - 1] != 0:
        raise ConfigError(FP + ".gexp_q14[%d]" % (GEXP_POINTS - 1), "must be 0 (table end)")

    LP = "node.loss"
    lo_ = _get(nd, "loss", "node")
    c.temps_cc = _ints(lo_, "temps_cc", LP, 1, MAX_LOSS_TEMPS, -5000, 15000, True)
    nt = c.loss_nt = len(c.temps_cc)
    vrows = _get(lo_, "v_um_s", LP)
    frows = _get(lo_, "force_n", LP)
    for f, rows in ((LP + ".v_um_s", vrows), (LP + ".force_n", frows)):
        if type(rows) is not list or len(rows) != n:
            raise ConfigError(f, "must be a list of %d entries (one per rope)" % n)
    nv = 0
    for i in range(n):
        f = "%s.v_um_s[%d]" % (LP, i)
        row = _ints(vrows, i, LP + ".v_um_s", 2, MAX_LOSS_POINTS, 0, 1 << 19, True)
        if row[0] != 0:
            raise ConfigError(f + "[0]", "must be 0 (zero flow)")
        if i == 0:
            nv = len(row)
            c.v_um_s = array.array("i", bytes(4 * n * nv))
            c.force_n = array.array("i", bytes(4 * n * nt * nv))
        elif len(row) != nv:
            raise ConfigError(f, "length %d differs from rope 0's %d" % (len(row), nv))
        for j in range(nv):
            c.v_um_s[i * nv + j] = row[j]
        f = "%s.force_n[%d]" % (LP, i)
        if type(frows[i]) is not list or len(frows[i]) != nt:
            raise ConfigError(f, "must be a list of %d rows (one per temperature)" % nt)
        for t in range(nt):
            row = _ints(frows[i], t, f, nv, nv, -(1 << 16), 1 << 16)
            if row[0] != 0:
                raise ConfigError("%s[%d][0]" % (f, t), "must be 0 (no loss at zero flow)")
            for j in range(nv):
                c.force_n[(i * nt + t) * nv + j] = row[j]
    c.loss_nv = nv

    SP = "node.shaft"
    if c.max_pulses_per_sample * c.mm_per_pulse_q16 >= 1 << 28:
        raise ConfigError(SP + ".max_pulses_per_sample", "times mm_per_pulse_q16 exceeds 2**28")
    if c.max_pulses_per_sample * c.mm_per_pulse_q16 * c.window >= 1 << 29:
        raise ConfigError(SP + ".max_pulses_per_sample", "a frame window's travel exceeds 2**29")
    c.marks_mm = _ints(_get(nd, "shaft", "node"), "marks_mm", SP, 0, MAX_MARKS, -100000, 5000000, True)
    return c


def load(path="/node.json"):
    """Read and parse a node.json from flash; raise OSError, ValueError or ConfigError."""
    import json
    with open(path) as f:
        doc = json.load(f)
    return parse(doc)


def identity(doc):
    """(node_id, key) of a document's node section when both are valid, else None.

    A refused config usually still names its node; its config-fault status
    frames then carry that id and MAC so a host holding the node's key accepts
    them (docs/protocol.md)."""
    try:
        nd = _get(doc, "node", "")
        return _int(nd, "node_id", "node", 0, 255), bytes(list(_ints(nd, "key", "node", 16, 32, 0, 255)))
    except ConfigError:
        return None


def load_for_boot(path="/node.json"):
    """(cfg, node_id, key, reason) for a HAL at boot; never raises.

    A valid file gives (Config, its node_id, its key, None). Otherwise cfg is
    None, reason says why, and node_id, key identify the config-fault status
    frames: the file's own (`identity`) when readable, else 255 and no key."""
    import json
    try:
        with open(path) as f:
            doc = json.load(f)
    except Exception as e:  # missing, unreadable, not JSON: no identity to be had
        return None, 255, b"", "config %s unreadable: %r" % (path, e)
    try:
        cfg = parse(doc)
        return cfg, cfg.node_id, cfg.key, None
    except ConfigError as e:
        reason = "config %s refused: %s: %s" % (path, e.field, e.reason)
    except Exception as e:  # e.g. nesting too deep for _canon: refused all the same
        reason = "config %s refused: %r" % (path, e)
    ident = identity(doc) or (255, b"")
    return None, ident[0], ident[1], reason


def release():
    """Forget this module after boot, so that a gc.collect() can free its code.

    The validator runs once, at boot, yet loaded from a .mpy file (not frozen)
    its bytecode (~11 KB) stays in RAM for as long as anything refers to the
    module. This drops the import system's references: sys.modules and the
    package's `config` attribute. The caller drops its own (the module, its
    functions and ConfigError instances; a Config keeps none of them, as its
    class has no methods, and neither does a Node built from a Config or from
    None) and calls gc.collect() after this returns: while this runs, the
    module's code is still in use. A HAL releases it before importing
    ropenode.node, so the two modules' code is never in RAM at once
    (hal_board._boot). A later import loads the module again.
    """
    import sys
    pkg = sys.modules.get("ropenode")
    for name in ("config", "crc16"):  # crc16 checks the config only
        sys.modules.pop("ropenode." + name, None)
        if pkg is not None and hasattr(pkg, name):
            delattr(pkg, name)  # set by the import of the submodule
