"""Node behaviour: config-fault status frames (signed with the refused file's identity), NAMUR exclusion, stable LuGre, shaft depth,
frame seq monotonic across resets (boot counter file).

Runs under CPython (pytest) and the real MicroPython (tests/run_micropython.py).
"""
import array
import json
import os
import random
import struct

from firmware_rig import frame_raw, node_doc

from ropenode import bootseq, layout
from ropenode.bootseq import FrameSeq
from ropenode.config import ConfigError, canonical, load_for_boot, parse
from ropenode.crc16 import crc16
from ropenode.frame import Hmac
from ropenode.node import K, Node

N = 4
MID = 30000      # mid-scale counts for pressure (~13.4 MPa) and displacement


def _rec(p=MID, x=MID, batt=60000, temp=0xFFFF, count=0, hall=0):
    r = array.array("H", [p] * N + [x] * N + [batt, temp, count & 0xFFFF, hall])
    return r


def _decode(wire, n):
    raw = frame_raw(wire, n)
    h = struct.unpack_from(layout.HEADER_FMT, raw, 0)
    ropes = []
    o = layout.HEADER_LEN
    for _ in range(layout.ropes_in(len(raw))):
        ropes.append(struct.unpack_from(layout.ROPE_FMT, raw, o))
        o += layout.ROPE_LEN
    tail = struct.unpack_from(layout.TAIL_FMT, raw, o)
    return h, ropes, tail


def _run(node, rec, samples):
    buf = bytearray(layout.MAX_WIRE_LEN)
    out = []
    for _ in range(samples):
        if node.sample(rec):
            out.append(_decode(buf, node.frame_into(buf)))
    return out


def test_missing_config_sends_status_frames_and_never_crashes():
    for cfg in (None, ConfigError("crc", "mismatch")):
        node = Node(cfg)
        frames = _run(node, _rec(), 100)
        frames += _run(node, array.array("H", [0xFFFF] * 3), 20)  # wrong length: ignored
        assert len(frames) == 6
        for k, (h, ropes, tail) in enumerate(frames):
            assert h[1] == layout.KIND_STATUS and h[6] & layout.ST_CONFIG_FAULT
            assert h[4] == k and ropes == []
            assert h[5] == (k + 1) * 100  # 20 samples at 200 Hz each


def test_frame_time_is_node_time_modulo_2_32_after_weeks_of_running():
    # sec * 1000 passes 2**30 after 12.4 days and 2**32 after 49.7: the node forms the
    # u32 from 16-bit halves, and the wire carries node time modulo 2**32
    buf = bytearray(layout.MAX_WIRE_LEN)
    for cfg in (parse(node_doc()), None):
        node = Node(cfg)
        _run(node, _rec(), 20)
        for sec, sub in ((1073741, 199), (1100000, 100), (4294967, 60), (4294968, 20), (999999999, 0)):
            if cfg is None:
                node.sec, node.sub = sec, sub
            else:
                node.S[K.OUT_SEC], node.S[K.OUT_SUB] = sec, sub
            h = _decode(buf, node.frame_into(buf))[0]
            assert h[5] == (sec * 1000 + sub * 5) % (1 << 32), (cfg is None, sec, sub, h[5])


def test_bad_config_document_gives_status_frames():
    doc = node_doc()
    doc["crc"] ^= 1
    try:
        cfg = parse(doc)
    except ConfigError as e:
        cfg = e
    frames = _run(Node(cfg), _rec(), 40)
    assert [f[0][6] & layout.ST_CONFIG_FAULT for f in frames] == [layout.ST_CONFIG_FAULT] * 2


def _write_doc(doc, tag):
    path = _boot_path("cfg-" + tag)
    with open(path, "w") as f:
        f.write(doc if type(doc) is str else json.dumps(doc))
    return path


def _boot_with(doc, tag):
    """config.load_for_boot on `doc` written to a file (None: no file at all)."""
    path = _boot_path("cfg-" + tag) if doc is None else _write_doc(doc, tag)
    try:
        return load_for_boot(path)
    finally:
        _cleanup(path)


def _resigned(doc):
    """doc with its CRC made right again, so the refusal is for the field changed."""
    doc["crc"] = crc16(canonical(doc["node"]))
    return doc


def _bad_docs_with_identity():
    """(tag, document refused for another reason than its node_id or key, field named)."""
    out = []
    doc = node_doc()
    doc["crc"] ^= 1
    out.append(("crc", doc, "crc"))
    doc = node_doc()
    doc["node"]["ropes"] = 9
    out.append(("field", _resigned(doc), "node.ropes"))
    doc = node_doc()
    doc["schema"] = 2
    out.append(("schema", doc, "schema"))
    doc = node_doc()
    del doc["node"]["friction"]
    out.append(("missing", _resigned(doc), "node.friction"))
    return out


def _mac_ok(node, key):
    """The next frame of `node` carries the MAC of `key` (frame.Hmac, truncated)."""
    buf = bytearray(layout.MAX_WIRE_LEN)
    while not node.sample(_rec()):
        pass
    n = node.frame_into(buf)
    raw = frame_raw(buf, n)
    body = len(raw) - layout.MAC_LEN - layout.CRC_LEN
    return raw[body:body + layout.MAC_LEN] == Hmac(key).digest(raw[:body])[:layout.MAC_LEN]


def test_refused_config_still_signs_status_frames_with_its_identity():
    key = bytes(node_doc()["node"]["key"])
    for tag, doc, field in _bad_docs_with_identity():
        cfg, node_id, k, reason = _boot_with(doc, tag)
        assert cfg is None and (node_id, k) == (1, key), tag
        assert "refused" in reason and field + ":" in reason, reason
        frames = _run(Node(cfg, node_id, k), _rec(), 40)
        assert len(frames) == 2
        for h, ropes, tail in frames:
            assert h[1] == layout.KIND_STATUS and h[2] == 1 and h[6] & layout.ST_CONFIG_FAULT
            assert ropes == []
        assert _mac_ok(Node(cfg, node_id, k), key) and not _mac_ok(Node(cfg, node_id, k), b"")


def test_config_without_a_readable_identity_sends_as_node_255_unkeyed():
    cases = [("none", None), ("notjson", "{not json"), ("list", "[1, 2]")]
    for field, bad in (("node_id", 300), ("node_id", "1"), ("key", [1] * 15), ("key", [1] * 15 + [256]),
                       ("key", "0011")):
        doc = node_doc()
        doc["node"][field] = bad
        cases.append((field, _resigned(doc) if type(bad) is not str else doc))
    doc = node_doc()
    doc["node"] = [1]
    cases.append(("node", doc))
    for tag, doc in cases:
        cfg, node_id, key, reason = _boot_with(doc, tag)
        assert cfg is None and (node_id, key) == (255, b""), tag
        assert reason, tag
        frames = _run(Node(cfg, node_id, key), _rec(), 20)
        assert frames[0][0][2] == 255 and frames[0][0][6] & layout.ST_CONFIG_FAULT
        assert _mac_ok(Node(cfg, node_id, key), b"")


def test_valid_config_boots_with_its_identity():
    cfg, node_id, key, reason = _boot_with(node_doc(), "ok")
    assert reason is None and cfg.ropes == N
    assert (node_id, key) == (1, bytes(node_doc()["node"]["key"]))


def test_steady_input_gives_steady_frames():
    node = Node(parse(node_doc()))
    frames = _run(node, _rec(), 200)
    assert len(frames) == 10
    h, ropes, tail = frames[-1]
    assert h[1] == layout.KIND_DATA and h[3] == 0
    assert h[6] & layout.ST_PRESSURE_FAULT == 0 and h[6] & layout.ST_TEMP_ABSENT
    # still piston: no flow, no friction: T = p A; mid counts -> 13.4 MPa * 7.854e-3 m^2
    pa = (MID - 9600) * 25e6 / 38400
    t_dan = pa * 0.00785398 / 10
    for mean, lo, hi, kpa, pos in ropes:
        assert lo == mean == hi and abs(mean - t_dan) <= 1, (mean, t_dan)
        assert pos == 31  # mid counts: 3.125 mm from mid-stroke (docs/model.md), 0.1 mm rounded
        assert abs(kpa - pa / 1000) <= 1.5  # kPa are truncated
    assert [f[0][4] for f in frames] == list(range(10))
    assert tail[2] == 12000  # 60000 counts * 0.2 mV


def test_namur_fault_flags_and_excludes_the_rope():
    node = Node(parse(node_doc()))
    _run(node, _rec(), 40)
    rec = _rec()
    for c in (8639, 50401, 0, 65535):  # below 3.6 mA, above 21 mA, rails
        rec[1] = c
        frames = _run(node, rec, 20)
        h, ropes, tail = frames[0]
        assert h[3] == 0x02 and h[6] & layout.ST_PRESSURE_FAULT
        assert ropes[1][:4] == (layout.TENSION_ABSENT,) * 3 + (layout.RAW_KPA_ABSENT,)
        assert ropes[1][4] == 31  # its position is still seen
        assert ropes[0][0] == ropes[2][0] == ropes[3][0] != layout.TENSION_ABSENT
        assert node.S[K.GOOD] == 0b1101
    rec[1] = 8640  # 3.6 mA exactly is still a signal
    frames = _run(node, rec, 20)
    assert frames[0][0][3] == 0 and frames[0][1][1][0] != layout.TENSION_ABSENT


def test_displacement_fault_flags_the_rope():
    node = Node(parse(node_doc()))
    rec = _rec()
    rec[N + 3] = 0
    h, ropes, tail = _run(node, rec, 20)[0]
    assert h[3] == 0x80 and h[6] & layout.ST_DISPLACEMENT_FAULT
    assert ropes[3][0] == layout.TENSION_ABSENT
    assert ropes[3][4] == layout.POS_ABSENT and ropes[2][4] == 31
    assert tail[4] == 0 and h[6] & layout.ST_STROKE_LIMIT == 0


# The shipped node.json's displacement channels: counts 9600..48000 over -0.05..0.05 m.
Q8 = 256e6  # um/256 per m


def _counts(x_m):
    return round(9600 + (x_m + 0.05) * 384000)


def _limits(nd, key):
    """Node section nd's per-rope `key` (a stroke or travel limit)."""
    v = nd[key]
    return [v] * N if type(v) is int else v


def _stroke_cfg(**over):
    """The shipped config with the travel at +-45 mm and the stroke margins at +-40 mm."""
    doc = node_doc()
    nd = doc["node"]
    nd["travel_lo_q8um"] = round(-0.045 * Q8)
    nd["stroke_lo_q8um"] = [round(-0.040 * Q8)] * N
    nd["stroke_hi_q8um"] = [round(0.040 * Q8)] * N
    nd["travel_hi_q8um"] = round(0.045 * Q8)
    nd.update(over)
    return parse(_resigned(doc))


def test_position_mean_over_the_window_in_01mm():
    node = Node(parse(node_doc()))
    rec = _rec()
    buf = bytearray(layout.MAX_WIRE_LEN)
    frames = []
    xs = []
    for k in range(40):  # rope 0 ramps -20 mm -> +19 mm, rope 1 steps, rope 2 still, rope 3 at -37.5 mm
        xs.append(-0.020 + 0.001 * k)
        rec[N] = _counts(xs[-1])
        rec[N + 1] = _counts(0.010 if k % 20 < 5 else -0.002)
        rec[N + 2] = MID
        rec[N + 3] = _counts(-0.0375)
        if node.sample(rec):
            frames.append(_decode(buf, node.frame_into(buf)))
    assert len(frames) == 2
    for w, (h, ropes, tail) in enumerate(frames):
        want = sum(xs[20 * w:20 * w + 20]) / 20 * 1e4  # 0.1 mm
        assert abs(ropes[0][4] - want) <= 0.51, (w, ropes[0][4], want)
        assert ropes[1][4] == round((5 * 0.010 - 15 * 0.002) / 20 * 1e4) == 10
        assert ropes[2][4] == 31 and ropes[3][4] == -375
        assert tail[4] == 0 and h[6] & layout.ST_STROKE_LIMIT == 0
    assert (frames[0][1][0][4], frames[1][1][0][4]) == (-105, 95)


def test_one_sample_in_the_stroke_margin_sets_its_bit_for_the_window():
    node = Node(_stroke_cfg())
    rec = _rec()
    _run(node, rec, 20)
    rec[N + 1] = _counts(0.042)   # rope 1 into the extended end's margin for one sample
    assert node.sample(rec) is False
    rec[N + 1] = MID
    (h, ropes, tail), = _run(node, rec, 19)
    assert tail[4] == 16 << 1 and h[6] & layout.ST_STROKE_LIMIT
    assert h[3] == 0 and h[6] & layout.ST_DISPLACEMENT_FAULT == 0
    (h, ropes, tail), = _run(node, rec, 20)  # the next window: clear again
    assert tail[4] == 0 and h[6] & layout.ST_STROKE_LIMIT == 0
    rec[N + 3] = _counts(-0.0401)  # rope 3 in the retracted end's margin, rope 0 at the extended's
    rec[N] = _counts(0.0401)
    (h, ropes, tail), = _run(node, rec, 20)
    assert tail[4] == (1 << 3) | (16 << 0) and h[6] & layout.ST_STROKE_LIMIT
    assert ropes[3][4] == -401 and ropes[0][4] == 401 and h[3] == 0
    rec[N + 3] = _counts(-0.039)  # inside the margins: no bit
    rec[N] = _counts(0.039)
    (h, ropes, tail), = _run(node, rec, 20)
    assert tail[4] == 0


def test_a_position_exactly_at_a_stroke_limit_is_in_the_margin():
    cfg = parse(node_doc())
    d = cfg.displacement  # rope 2's channel: counts_lo, .., q8um_at_lo, mul, shift

    def x_of(c):
        return d[12 + 3] + (((c - d[12]) * d[12 + 4]) >> d[12 + 5])
    lo, hi = x_of(13440), x_of(44928)
    m = round(0.040 * Q8)
    node = Node(_stroke_cfg(stroke_lo_q8um=[-m, -m, lo, -m], stroke_hi_q8um=[m, m, hi, m]))
    rec = _rec()
    for c, bits in ((13440, 1 << 2), (13441, 0), (44928, 16 << 2), (44927, 0)):
        rec[N + 2] = c
        (h, ropes, tail), = _run(node, rec, 20)
        assert node.S[K.X_Q8UM + 2] == x_of(c) and tail[4] == bits, (c, tail[4])


def test_a_reading_beyond_the_travel_is_a_displacement_fault_never_a_stroke():
    node = Node(_stroke_cfg())
    rec = _rec()
    _run(node, rec, 20)
    held = node.S[K.X_Q8UM + 2]
    rec[N + 2] = _counts(0.047)   # beyond +45 mm for one sample: a broken transmitter
    rec[N] = _counts(-0.047)      # and rope 0 beyond -45 mm
    node.sample(rec)
    assert node.S[K.X_Q8UM + 2] == held and node.S[K.FAULTS] == (16 << 2) | (16 << 0)  # held, as for NAMUR
    rec[N + 2] = rec[N] = MID
    (h, ropes, tail), = _run(node, rec, 19)
    assert h[3] == (16 << 2) | (16 << 0) and h[6] & layout.ST_DISPLACEMENT_FAULT
    assert tail[4] == 0 and h[6] & layout.ST_STROKE_LIMIT == 0
    assert ropes[2][4] == 31 and ropes[0][4] == 31  # the mean of the healthy samples only
    rec[N + 2] = _counts(0.047)   # beyond for a whole window: no position, no tension
    (h, ropes, tail), = _run(node, rec, 20)
    assert ropes[2][4] == layout.POS_ABSENT and ropes[2][0] == layout.TENSION_ABSENT
    assert h[3] == 16 << 2 and tail[4] == 0
    # without travel limits (an older node.json) the same reading is a position in the margin
    node = Node(_stroke_cfg(travel_lo_q8um=-(1 << 29), travel_hi_q8um=1 << 29))
    (h, ropes, tail), = _run(node, rec, 20)
    assert h[3] == 0 and tail[4] == 16 << 2 and ropes[2][4] == 470


def test_the_travel_check_is_the_counts_whose_position_is_within_the_travel():
    """The node folds the travel limits into its channels' count limits at boot: a count is
    a displacement fault exactly when it is outside the loop's limits or its position (um/256)
    outside the travel; checked on both sides of where that changes (found by bisection: the
    positions rise with the counts) and at every 257th count."""
    cfg = parse(node_doc())
    d = cfg.displacement
    x0 = d[3] + (((30000 - d[0]) * d[4]) >> d[5])
    narrow = {"travel_lo_q8um": x0 + 1, "stroke_lo_q8um": x0 + 2, "stroke_hi_q8um": x0 + 3,
              "travel_hi_q8um": x0 + 4}  # between two counts' positions: no count is within it
    counts = []
    for cfg in (cfg, _stroke_cfg(), _stroke_cfg(travel_lo_q8um=x0, stroke_lo_q8um=x0 + 1, stroke_hi_q8um=x0 + 19999,
                                                travel_hi_q8um=x0 + 20000), _stroke_cfg(**narrow)):
        node = Node(cfg)
        rec = _rec()
        ch = cfg.displacement[0:6]  # every rope's channel is the same here
        lo, hi = cfg.travel_lo_q8um[0], cfg.travel_hi_q8um[0]
        assert list(cfg.displacement) == list(ch) * N and list(cfg.travel_hi_q8um) == [hi] * N

        def pos(c):
            return ch[3] + (((c - ch[0]) * ch[4]) >> ch[5])

        def within(c):
            return ch[1] <= c <= ch[2] and lo <= pos(c) <= hi

        def first(ok):  # the least count in 0..65536 from which ok holds (ok rises with the count)
            a, b = 0, 65536
            while a < b:
                m = (a + b) // 2
                if ok(m):
                    b = m
                else:
                    a = m + 1
            return a
        assert ch[4] > 0  # positions rise with the counts: the window of counts within is one run
        start = max(ch[1], first(lambda c: pos(c) >= lo))
        end = min(ch[2], first(lambda c: pos(c) > hi) - 1)
        todo = set(range(0, 65536, 257))
        for e in (start, end + 1):
            todo.update(range(max(e - 2, 0), min(e + 2, 65536)))
        for c in sorted(todo):
            for i in range(N):
                rec[N + i] = c
            node.sample(rec)
            assert node.S[K.FAULTS] == (0 if within(c) else 0xF0), (c, node.S[K.FAULTS])
        counts.append(max(0, end - start + 1))
    assert counts[0] > counts[1] > counts[2] > 0 == counts[3], counts
    # 384 counts per mm: 90 mm of travel and 20000 um/256 (30 counts of 666.7), each +-1
    assert abs(counts[1] - 34560) <= 1 and abs(counts[2] - 30) <= 1, counts


def test_the_position_zero_shifts_only_the_positions():
    """The compensation works on position differences: moving the displacement calibration's
    zero by 50 mm (and the limits with it) leaves every tension bit for bit, and moves the
    reported positions by 500 x 0.1 mm."""
    shift = round(0.050 * Q8)
    doc = node_doc()
    nd = doc["node"]
    for ch in nd["displacement"]:
        ch["q8um_at_lo"] += shift
    for key in ("travel_lo_q8um", "stroke_lo_q8um", "stroke_hi_q8um", "travel_hi_q8um"):
        if key in nd:  # (absent: no limit to move)
            nd[key] = [x + shift for x in _limits(nd, key)]
    a = Node(parse(node_doc()))
    b = Node(parse(_resigned(doc)))
    rec = _rec()
    buf = bytearray(layout.MAX_WIRE_LEN)
    seed = 12345
    for k in range(600):
        seed = (seed * 1103515245 + 12345) & 0x7FFFFFFF
        for i in range(N):
            t = (k * (i + 3) * 5) % 400
            rec[N + i] = _counts(-0.03 + 0.0003 * (t if t < 200 else 400 - t))
            rec[i] = MID + ((seed >> (4 + i)) % 801) - 400
        ra = a.sample(rec)
        assert ra == b.sample(rec)
        assert a.rope(K.TENSION_N) == b.rope(K.TENSION_N), k
        if ra:
            fa = _decode(buf, a.frame_into(buf))
            fb = _decode(buf, b.frame_into(buf))
            assert fa[0][3] == fb[0][3] == 0 and fa[2] == fb[2]
            for ra_, rb_ in zip(fa[1], fb[1]):
                assert ra_[:4] == rb_[:4] and rb_[4] == ra_[4] + 500, (k, ra_, rb_)


def test_lugre_stays_bounded_where_explicit_euler_diverges():
    cfg = parse(node_doc())
    node = Node(cfg)
    doc = node_doc()["physical"]
    fr = doc["friction"]
    sigma0 = fr["sigma0"]
    h = 1 / cfg.sample_hz
    v = 0.2                      # m/s, the node's velocity limit
    p_mpa = 13.4
    fs = fr["Fs"]["intercept"] + fr["Fs"]["slope"] * p_mpa
    fc = fr["Fc"]["intercept"] + fr["Fc"]["slope"] * p_mpa
    vs = fr["vs"]["intercept"] + fr["vs"]["slope"] * p_mpa
    import math
    g = fc + (fs - fc) * math.exp(-(v / vs) ** 2)
    assert h * sigma0 * v / g > 2  # explicit Euler is unstable here
    z = 0.0
    for _ in range(40):
        z = z + h * (v - sigma0 * v * z / g)
    assert abs(sigma0 * z) > 1e6  # explicit Euler blew up (N)
    # the node: 13.4 MPa, pistons driven end to end at the velocity limit, reversing
    dc = doc["displacement_channels"][0]
    c_per_m = (dc["counts_hi"] - dc["counts_lo"]) / (dc["range_m"][1] - dc["range_m"][0])
    step = int(v * h * c_per_m) + 1  # counts per sample: beyond v_max, so dx is clamped
    x = MID
    rec = _rec()
    saw_max = False
    for k in range(400):
        x += step if (k // 50) % 2 == 0 else -step   # reversals every 50 samples
        for i in range(N):
            rec[N + i] = x
        node.sample(rec)
        for i in range(N):
            assert abs(node.S[K.ZF + i]) <= node.S[K.G + i] + 16, (k, node.S[K.ZF + i], node.S[K.G + i])
        saw_max = saw_max or abs(node.S[K.V_UM_S]) == int(v * 1e6)
    assert saw_max  # the velocity limit was reached
    # sliding at the limit: zf has settled to sgn(v) g(v, p) within a few newtons
    p_mpa = (node.S[K.P_KPA16] >> 4) / 1000
    fs = fr["Fs"]["intercept"] + fr["Fs"]["slope"] * p_mpa
    fc = fr["Fc"]["intercept"] + fr["Fc"]["slope"] * p_mpa
    vs = fr["vs"]["intercept"] + fr["vs"]["slope"] * p_mpa
    g = fc + (fs - fc) * math.exp(-(v / vs) ** 2)
    assert node.S[K.V_UM_S] == -int(v * 1e6)
    assert abs(node.S[K.ZF] / 16 + g) < 5, (node.S[K.ZF] / 16, g)


def test_depth_integrates_pulses_and_snaps_at_hall_marks():
    node = Node(parse(node_doc()))
    count = 0
    frames = []
    buf = bytearray(layout.MAX_WIRE_LEN)
    for k in range(600):       # 3 s down at 10 pulses/sample = 20 m/s
        count += 10
        if node.sample(_rec(count=count)):
            frames.append(_decode(buf, node.frame_into(buf)))
    assert node.S[K.DEPTH_MM] == 599 * 10 * 10
    assert frames[-1][2][1] == 20000  # mm/s
    node.S[K.DEPTH_MM] = 5800       # drifted 0.8 m past the 5 m mark
    node.sample(_rec(count=count, hall=1))
    assert node.S[K.DEPTH_MM] == 5000
    node.S[K.DEPTH_MM] = 150000     # far from any mark: no snap
    node.sample(_rec(count=count, hall=0))
    node.sample(_rec(count=count, hall=3))
    assert node.S[K.DEPTH_MM] == 150000


def test_counter_glitch_is_ignored_and_flagged():
    node = Node(parse(node_doc()))
    node.sample(_rec(count=100))
    node.sample(_rec(count=9000))
    assert node.S[K.DEPTH_MM] == 0 and node.S[K.SHAFT_FAULT]


def test_config_fault_node_samples_without_allocating():
    import micropython
    node = Node(None)
    rec = _rec()
    ready = 0
    micropython.heap_lock()
    try:
        for _ in range(200):
            if node.sample(rec):
                ready += 1
    finally:
        micropython.heap_unlock()
    assert ready == 10


def test_record_of_the_wrong_length_is_refused():
    node = Node(parse(node_doc()))
    for words in (2 * N + 3, 2 * N + 5, 0):
        try:
            node.sample(array.array("H", [MID] * words))
        except ValueError as e:
            assert "words" in str(e)
        else:
            raise AssertionError("accepted a record of %d words" % words)
    assert node.sample(_rec()) is False  # and the node goes on


def test_kernel_copies_of_shared_constants_agree():
    """kernel.py restates a few constants (viper inlines only its own module's consts)."""
    from ropenode import config
    assert (K.TEMP_ABSENT, K.TENSION_ABSENT, K.RAW_KPA_ABSENT, K.POS_ABSENT) == (
        layout.OIL_TEMP_ABSENT, layout.TENSION_ABSENT, layout.RAW_KPA_ABSENT, layout.POS_ABSENT)
    assert K.ROPES_MAX == layout.MAX_ROPES and K.GEXP_POINTS == config.GEXP_POINTS
    assert K.TEMPS_MAX == config.MAX_LOSS_TEMPS


def _boot_path(tag):
    """A fresh boot-counter path in /tmp (no tempfile module in MicroPython)."""
    p = "/tmp/ropemon-bootseq-%s-%s-%08x" % (tag, __import__("sys").implementation.name, random.getrandbits(32))
    for q in (p, p + ".tmp"):
        try:
            os.remove(q)
        except OSError:
            pass
    return p


def _cleanup(p):
    for q in (p, p + ".tmp"):
        try:
            os.remove(q)
        except OSError:
            pass


def test_frame_seq_increases_across_resets():
    path = _boot_path("resets")
    try:
        cfg = parse(node_doc())
        seqs = []
        for boot in range(3):  # three boots of the node, 3 frames each
            frames = _run(Node(cfg, seq=FrameSeq(path)), _rec(), 60)
            seqs += [h[4] for h, _, _ in frames]
            assert bootseq.read_boot(path) == boot
        assert seqs == [(b << 20) | k for b in range(3) for k in range(3)]
        # a config-fault node counts on the same boot counter
        frames = _run(Node(None, seq=FrameSeq(path)), _rec(), 40)
        assert [h[4] for h, _, _ in frames] == [3 << 20, (3 << 20) | 1]
    finally:
        _cleanup(path)


def _seq(halves):
    """The u32 seq of FrameSeq's (low, high) 16-bit halves."""
    return halves[0] | (halves[1] << 16)


def test_without_a_boot_file_seq_starts_at_zero_and_writes_nothing():
    fs = FrameSeq()
    assert [_seq(fs.next()) for _ in range(3)] == [0, 1, 2] and fs.boot == 0
    assert [h[4] for h, _, _ in _run(Node(None), _rec(), 60)] == [0, 1, 2]


def test_count_overflow_bumps_and_persists_the_boot_counter():
    path = _boot_path("overflow")
    try:
        fs = FrameSeq(path)
        fs.count = bootseq.COUNT_MASK - 1  # 29 h of frames at 10 Hz later
        assert [_seq(fs.next()) for _ in range(3)] == [0xFFFFE, 0xFFFFF, 1 << 20]
        assert bootseq.read_boot(path) == 1   # persisted at the wrap, not per frame
        assert _seq(fs.next()) == (1 << 20) | 1
        assert _seq(FrameSeq(path).peek()) == 2 << 20  # the next boot is newer still
    finally:
        _cleanup(path)


def test_boot_counter_file_damage_and_wrap():
    path = _boot_path("damage")
    try:
        # cut between writing the temp file and the rename (FAT fallback): the temp file counts
        with open(path + ".tmp", "w") as f:
            f.write("41\n")
        assert bootseq.read_boot(path) == 41 and FrameSeq(path).boot == 42
        assert bootseq.read_boot(path) == 42
        # unreadable: start again at 0 (the host refuses it until an operator accepts: docs/protocol.md)
        _cleanup(path)
        with open(path, "w") as f:
            f.write("garbage")
        assert FrameSeq(path).boot == 0
        # 4096 boots wrap the 12-bit counter to 0
        with open(path, "w") as f:
            f.write("4095\n")
        fs = FrameSeq(path)
        assert fs.boot == 0 and _seq(fs.next()) == 0
    finally:
        _cleanup(path)


def test_an_unwritable_boot_file_does_not_stop_the_node():
    fs = FrameSeq("/nonexistent-ropemon-dir/bootcount")
    assert fs.boot == 0 and [_seq(fs.next()) for _ in range(2)] == [0, 1]
