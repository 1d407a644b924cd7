"""Zero heap allocation per sample: Node.sample under micropython.heap_lock().

Runs under the real `micropython` (tests/run_micropython.py), where any heap
allocation inside heap_lock() raises MemoryError, and on the 32-bit WebAssembly
port (test_int32_wasm_cpython.py), where an int beyond +-2**30 allocates too.
Under CPython (pytest) heap_lock is the shim's no-op: the same inputs then
only prove the hot path runs without error and closes its windows.

The input stream (`hot_path_records`) covers what a shaft throws at the node:
rest, slow ramps with direction reversals, shock steps, ADC rails, NAMUR and
displacement faults just beyond and exactly on their thresholds, full-range
random words, speed-counter wrap, Hall marks; with the shipped config and
with variants (oil temperature input fitted, 1 and 3 ropes).
"""
import array
import gc
import json
import sys

import micropython

from ropenode.layout import MAX_WIRE_LEN

ON_MICROPYTHON = sys.implementation.name == "micropython"
SAMPLES = 2400  # >= 1000 locked samples, 12 frame windows at the default 200/10 Hz


def load_node_json():
    """The shipped node.json: the one beside the ropenode package on sys.path."""
    for d in sys.path:
        d = d or "."
        try:
            open(d + "/ropenode/__init__.py").close()
            with open(d + "/node.json") as f:
                return json.load(f)
        except OSError:
            pass
    raise OSError("firmware/node.json (beside firmware/ropenode) not found on sys.path")


def variant_doc(ropes=None, temp_fitted=False, compliance=False, noise_ref_q6=64, slide_span_q8um=1 << 20,
                step_max_counts=None, step_recover=None, stroke=False):
    """The shipped node.json changed (fewer ropes, an oil temperature input, the largest
    hydraulic compliance the node accepts with a warm-up, noise following from
    `noise_ref_q6`, slide following over `slide_span_q8um`, the pressure step check's
    limit and recovery, the travel and stroke margins of `stroke_doc`), CRC renewed."""
    from ropenode.config import canonical
    from ropenode.crc16 import crc16
    doc = load_node_json()
    nd = doc["node"]
    if ropes is not None:
        nd["ropes"] = ropes
        for key in ("pressure", "displacement"):
            nd[key] = nd[key][:ropes]
        for key in ("v_um_s", "force_n"):
            nd["loss"][key] = nd["loss"][key][:ropes]
        nd["friction"]["compliance_q"] = nd["friction"]["compliance_q"][:ropes]
        nd["friction"]["area_q8"] = nd["friction"]["area_q8"][:ropes]
        for key in ("play_q8um", "rest_play_q8um", "rest_q16um"):  # for 1..ropes healthy channels
            nd["friction"][key] = nd["friction"][key][:ropes]
        for key in ("travel_lo_q8um", "stroke_lo_q8um", "stroke_hi_q8um", "travel_hi_q8um"):
            if type(nd.get(key)) is list:
                nd[key] = nd[key][:ropes]
    if compliance:
        # k = 1 um/kPa: k times 100 MPa is 0.1 m, the config check's limit; stroke tracking
        # at its extremes (the fastest low-passes, areas 0.5 and 1.5 of the mean, a stroke
        # at every 1/256 um of e, no settling), so every branch of it runs; the rest hold
        # with a threshold of 8 um of activity, so ropes go quiet and wake again
        nd["friction"].update(rest_q16um=[8 << 16] * nd["ropes"],
                              rest_play_q8um=[p + 256 for p in nd["friction"]["play_q8um"]])
        # the pressure tracker at the extremes of its gains (the oscillator undamped at 0 Hz,
        # every gain +-1 in its scale, the rate as fine and the bounce as coarse as they go): it may run away, and its
        # clamps must hold it
        nd["friction"].update(tracker_a1_q14=32767, tracker_a2_q14=16383,
                              tracker_k_q14=[16384, -16384, 16384, -16384], tracker_v_shift=12,
                              tracker_b_shift=0)
        # noise following as fast as it goes: the streams' random counts take its ratio over
        # its whole range (half to twice), from a level of 1 kPa/16 (64) or the largest one
        nd["friction"].update(noise_ref_q6=noise_ref_q6, noise_shift=1)
        # slide following from 1 um of e over the given span (the largest: e's random values
        # fall both within and beyond it; 1: a share of 0 or all)
        nd["friction"].update(slide_lo_q8um=256, slide_span_q8um=slide_span_q8um)
        nd["friction"].update(compliance_q=[131071] * nd["ropes"], compliance_shift=9,
                              warmup_samples=400, alpha_e_q14=4096, stroke_q8um=1, stroke_vmin_q16=0,
                              stroke_settle=0, area_q8=[(128, 384)[i % 2] for i in range(nd["ropes"])])
    if step_max_counts is not None:  # 0: off (the shipped limit faults most of the test streams' steps)
        for ch in nd["pressure"]:
            ch["step_max_counts"] = step_max_counts
    if step_recover is not None:
        nd["step_recover"] = step_recover
    if stroke:
        stroke_doc(nd)
    if temp_fitted:
        # 4-20 mA = 9600..48000 counts = -20..+80 C; loss table rows clamp at both ends
        nd["temperature"] = {"fitted": 1, "counts_at_0c": 17280, "cc_mul": 8533, "cc_shift": 15,
                             "fault_lo_counts": 9000, "fault_hi_counts": 50400,
                             "assumed_cc": nd["temperature"]["assumed_cc"]}
    doc["crc"] = crc16(canonical(nd))
    return doc


def stroke_doc(nd):
    """Travel limits and stroke margins in node section `nd`: travel +-45 mm, the margins from
    +-40 mm (rope i's i mm further in): the streams' pistons (-52.5..57.5 mm between their
    channels' fault limits) run into the margins and beyond the travel."""
    q = 256000  # um/256 per mm
    n = nd["ropes"]
    nd["travel_lo_q8um"] = -45 * q
    nd["stroke_lo_q8um"] = [(i - 40) * q for i in range(n)]
    nd["stroke_hi_q8um"] = [(40 - i) * q for i in range(n)]
    nd["travel_hi_q8um"] = 45 * q
    return nd


def build_node(doc=None):
    """(node, ropes, per-rope channel limits) from the shipped config (or `doc`).

    Limits per rope: (pressure counts at 4 mA, NAMUR low and high fault
    thresholds, displacement counts_lo and its low/high fault thresholds),
    read from the validated Config (ropenode.config, per-rope int arrays).
    """
    from ropenode.config import parse
    from ropenode.node import Node
    cfg = parse(doc or load_node_json())
    node = Node(cfg)
    n = cfg.ropes
    chans = []
    for i in range(n):
        p = cfg.pressure[10 * i:10 * i + 3]
        d = cfg.displacement[6 * i:6 * i + 3]
        chans.append((p[0], p[1], p[2], d[0], d[1], d[2]))
    return node, n, chans


class Rand:
    """xorshift32: the same numbers under CPython, unix and wasm MicroPython."""

    def __init__(self, seed):
        self.s = seed & 0xFFFFFFFF or 1

    def u16(self):
        s = self.s
        s ^= (s << 13) & 0xFFFFFFFF
        s ^= s >> 17
        s ^= (s << 5) & 0xFFFFFFFF
        self.s = s
        return s >> 16

    def below(self, n):
        return self.u16() * n >> 16


def hot_path_records(ropes, chans, count, seed=1):
    """count sensor records (2N+4 words each, docs/data-formats.md) as one array('H')."""
    w = 2 * ropes + 4
    out = array.array("H", bytes(2 * w * count))
    rnd = Rand(seed)
    speed = 0
    seg = count // 8
    for k in range(count):
        part = k // seg if seg else 0
        b = k * w
        for i in range(ropes):
            c4, flo, fhi, dlo, dflo, dfhi = chans[i]
            c20 = c4 + (fhi - c4) * 16 // 17  # 20 mA, from 4 mA and the 21 mA fault line
            span = c20 - c4
            mid = c4 + span // 2
            dmid = dlo + (dfhi - dlo) // 2
            if part == 0:    # rest: constant loads, piston still
                p, x = mid, dmid
            elif part == 1:  # slow ramps with reversals (triangle wave, rope-specific phase)
                t = (k * (i + 1) * 97) % 4000
                tri = t if t < 2000 else 4000 - t
                p, x = c4 + span * tri // 2000, dlo + (dfhi - dlo) * tri // 2000
            elif part == 2:  # shocks: full-span pressure steps, piston end to end
                hi = (k // 7 + i) & 1
                p, x = (c20 if hi else c4), (dfhi if hi else dflo)
            elif part == 3:  # ADC rails: 0 and 65535 on every channel
                p = x = 0xFFFF if (k + i) & 1 else 0
            elif part == 4:  # one loop at a time just outside NAMUR NE43 / displacement range
                if i == (k // 10) % ropes:
                    p = flo - 1 if k & 1 else fhi + 1
                    x = dflo - 1 if k & 2 else dfhi + 1
                    p = min(max(p, 0), 0xFFFF)
                    x = min(max(x, 0), 0xFFFF)
                else:
                    p, x = mid, dmid
            elif part == 5:  # exactly on the fault thresholds (still valid), piston at both ends
                p = flo if k & 1 else fhi
                x = dflo if (k // 3) & 1 else dfhi
            else:            # full-range random words
                p, x = rnd.u16(), rnd.u16()
            out[b + i] = p
            out[b + ropes + i] = x
        if part == 3:
            batt, temp = (0xFFFF, 0) if k & 1 else (0, 0xFFFE)
        elif part >= 6:
            batt, temp = rnd.u16(), rnd.u16()
        else:
            batt, temp = 40000, 0xFFFF if part & 1 else 20000
        # speed counter: steady, reversing, wrapping, and random jumps
        if part == 2:
            speed = (speed + 3000) & 0xFFFF
        elif part >= 6:
            speed = rnd.u16()
        else:
            speed = (speed + (40 if (k // 50) & 1 else -40)) & 0xFFFF
        out[b + 2 * ropes] = batt
        out[b + 2 * ropes + 1] = temp
        out[b + 2 * ropes + 2] = speed
        out[b + 2 * ropes + 3] = (k // 13) & 3 if part != 6 else rnd.below(4)
    return out


def _sample_locked(node, recs, first, last, w, rec):
    """node.sample over records first..last-1 inside heap_lock.

    Returns (windows closed, -1) or (windows closed, index of the record that allocated).
    """
    ready = 0
    k = first
    micropython.heap_lock()
    try:
        while k < last:
            b = k * w
            for j in range(w):
                rec[j] = recs[b + j]
            if node.sample(rec):
                ready += 1
            k += 1
    except MemoryError:
        micropython.heap_unlock()
        return ready, k
    micropython.heap_unlock()
    return ready, -1


def run_hot_path(node, ropes, recs, count):
    """All records through node.sample, locked; frame_into (may allocate) between windows.

    Returns (samples, frames, [frame lengths]); raises AssertionError naming
    the record that allocated.
    """
    w = 2 * ropes + 4
    rec = array.array("H", bytes(2 * w))
    buf = bytearray(MAX_WIRE_LEN)
    lens = []
    for k in range(count):
        ready, bad = _sample_locked(node, recs, k, k + 1, w, rec)
        assert bad < 0, "node.sample allocated on record %d: %s" % (bad, list(recs[bad * w:bad * w + w]))
        if ready:
            n = node.frame_into(buf)
            assert 0 < n <= MAX_WIRE_LEN and buf[0] == 0 and buf[n - 1] == 0, n
            lens.append(n)
    return count, len(lens), lens


def _crc32_locked(raw, n, rnd, frames):
    """crc32_into over `frames` frames of n bytes (random, then all 0x00 and all 0xFF),
    each call inside heap_lock. Returns -1, or the frame whose CRC allocated."""
    from ropenode.crc32 import crc32_into
    for f in range(frames + 2):
        for j in range(n):
            raw[j] = rnd.u16() & 0xFF if f < frames else (0, 0xFF)[f - frames]
        micropython.heap_lock()
        try:
            crc32_into(raw, n)
        except MemoryError:
            micropython.heap_unlock()
            return f
        micropython.heap_unlock()
    return -1


def test_frame_crc32_is_allocation_free():
    """The frame's CRC-32 (ropenode.crc32) over a 4-rope frame's 60 bytes allocates nothing:
    under heap_lock here, and on the 32-bit wasm port (test_int32_wasm_cpython.py), where
    a 32-bit intermediate would be a long int and allocate too. On the unix port
    micropython.mem_total does not move either (its call frame stays off the heap)."""
    from ropenode import layout
    from ropenode.crc32 import crc32_into
    raw = bytearray(layout.frame_len(layout.MAX_ROPES))
    n = len(raw) - layout.CRC_LEN
    bad = _crc32_locked(raw, n, Rand(99), 300)
    assert bad < 0, "crc32_into allocated on frame %d" % bad
    if ON_MICROPYTHON and sys.platform == "linux":
        t0 = micropython.mem_total()
        for _ in range(100):
            crc32_into(raw, n)
        assert micropython.mem_total() == t0, micropython.mem_total() - t0


def test_inputs_cover_faults_and_rails():
    node, ropes, chans = build_node()
    recs = hot_path_records(ropes, chans, SAMPLES)
    w = 2 * ropes + 4
    c4, flo, fhi, dlo, dflo, dfhi = chans[0]
    words = [recs[k * w] for k in range(SAMPLES)]
    assert 0 in words and 0xFFFF in words
    assert flo - 1 in words and fhi + 1 in words and flo in words and fhi in words
    xs = [recs[k * w + ropes] for k in range(SAMPLES)]
    assert (dflo - 1 in xs or dflo == 0) and (dfhi + 1 in xs or dfhi == 0xFFFF)
    assert len(set(words)) > SAMPLES // 4


def test_stroke_variant_reaches_the_margins_and_beyond_the_travel():
    """The stroke variant's streams take every rope into both margins and beyond its travel
    (so the allocation, range and viper checks run those branches)."""
    from ropenode.node import K
    node, ropes, chans = build_node(variant_doc(stroke=True))
    recs = hot_path_records(ropes, chans, SAMPLES)
    w = 2 * ropes + 4
    rec = array.array("H", bytes(2 * w))
    strokes = 0
    travel = 0
    positions = 0
    for k in range(SAMPLES):
        rec[:] = recs[k * w:(k + 1) * w]
        in_counts = 0
        for i in range(ropes):
            if chans[i][4] <= rec[ropes + i] <= chans[i][5]:
                in_counts |= 16 << i
        if node.sample(rec):
            strokes |= node.S[K.OUT_STROKE]
            for i in range(ropes):
                if node.S[K.OUT_POS + i] != -32768:
                    positions |= 1 << i
        travel |= node.S[K.FAULTS] & in_counts  # faulted with its counts within their limits
    full = (1 << ropes) - 1
    assert strokes == full | (full << 4), strokes
    assert travel == full << 4, travel
    assert positions == full


def test_sample_is_allocation_free_over_1000_samples():
    node, ropes, chans = build_node()
    recs = hot_path_records(ropes, chans, SAMPLES)
    w = 2 * ropes + 4
    rec = array.array("H", bytes(2 * w))
    gc.collect()
    ready, bad = _sample_locked(node, recs, 0, SAMPLES, w, rec)
    assert bad < 0, "node.sample allocated on record %d: %s" % (bad, list(recs[bad * w:bad * w + w]))
    assert ready >= SAMPLES // 200  # windows did close while locked (default 20 samples each)


def test_sample_with_frames_between_windows():
    node, ropes, chans = build_node()
    recs = hot_path_records(ropes, chans, SAMPLES, seed=7)
    samples, frames, lens = run_hot_path(node, ropes, recs, SAMPLES)
    assert samples == SAMPLES and frames >= SAMPLES // 200
    assert max(lens) <= MAX_WIRE_LEN


def test_sample_allocation_free_with_temperature_input_and_one_rope():
    """The paths the shipped config does not take: oil temperature fitted
    (loss-table rows re-selected as the temperature moves), N = 1, and a hydraulic
    compliance with its warm-up (the LuGre position from pressure)."""
    for fitted, doc in ((True, variant_doc(temp_fitted=True)), (True, variant_doc(ropes=1, temp_fitted=True)),
                        (False, variant_doc(ropes=3, stroke=True)), (False, variant_doc(compliance=True)),
                        (False, variant_doc(compliance=True, step_max_counts=0, stroke=True)),
                        (False, variant_doc(compliance=True, step_max_counts=20000, step_recover=2))):
        node, ropes, chans = build_node(doc)
        recs = hot_path_records(ropes, chans, 1200, seed=ropes)
        w = 2 * ropes + 4
        for k in range(1200):  # temperature words across and beyond the input's range
            recs[k * w + 2 * ropes + 1] = (k * 53) & 0xFFFF if k % 3 else 9600 + (k * 37) % 38400
        rec = array.array("H", bytes(2 * w))
        ready, bad = _sample_locked(node, recs, 0, 1200, w, rec)
        assert bad < 0, "N=%d: node.sample allocated on record %d: %s" % (
            ropes, bad, list(recs[bad * w:bad * w + w]))
        assert ready == 1200 // node.window_len
        rec[2 * ropes + 1] = 30000  # the temperature input is read when fitted, ignored when not
        node.sample(rec)
        assert node.temp_cc == (((30000 - 17280) * 8533) >> 15 if fitted else -32768), node.temp_cc


def test_sample_keeps_no_heap_memory():
    """Nothing survives a sample: heap in use is unchanged over 1000 samples (GC off)."""
    if not ON_MICROPYTHON:
        assert getattr(micropython, "ROPEMON_SHIM", False)  # CPython has no gc.mem_alloc
        return
    node, ropes, chans = build_node()
    recs = hot_path_records(ropes, chans, 1000, seed=3)
    w = 2 * ropes + 4
    rec = array.array("H", bytes(2 * w))
    _sample_locked(node, recs, 0, 20, w, rec)
    gc.collect()
    gc.disable()
    try:
        before = gc.mem_alloc()
        for k in range(1000):
            b = k * w
            for j in range(w):
                rec[j] = recs[b + j]
            node.sample(rec)
        after = gc.mem_alloc()
    finally:
        gc.enable()
    assert after == before, after - before


def test_sample_uses_no_heap_even_transiently():
    """Stronger than heap_lock: micropython.mem_total (bytes ever handed out, unix
    port) does not move over 1000 samples, so no call frame of the hot path goes
    to the heap either (see test_heap_lock_cannot_see_heap_call_frames)."""
    if not ON_MICROPYTHON or sys.platform != "linux":
        assert not ON_MICROPYTHON or sys.platform == "webassembly"  # wasm: frames on its pystack
        return
    node, ropes, chans = build_node()
    recs = hot_path_records(ropes, chans, 1000, seed=4)
    w = 2 * ropes + 4
    rec = array.array("H", bytes(2 * w))
    t0 = micropython.mem_total()
    for k in range(1000):
        b = k * w
        for j in range(w):
            rec[j] = recs[b + j]
        node.sample(rec)
    assert micropython.mem_total() == t0, micropython.mem_total() - t0


def _thirteen_locals(a):
    b = a + 1; c = b + 1; d = c + 1; e = d + 1; f = e + 1; g = f + 1  # noqa: E702
    h = g + 1; i = h + 1; j = i + 1; k = j + 1; m = k + 1; n = m + 1  # noqa: E702
    return a + b + c + d + e + f + g + h + i + j + k + m + n


def test_heap_lock_cannot_see_heap_call_frames():
    """Why the benchmark also reports micropython.mem_total: a function with more
    than 11 words of locals and stack gets its frame from the heap (freed on
    return); under heap_lock MicroPython silently puts it on the C stack instead,
    so the locked proof passes while unlocked calls do use the heap."""
    if sys.platform != "linux" or not ON_MICROPYTHON:
        assert not ON_MICROPYTHON or sys.platform == "webassembly"  # wasm: pystack, no heap frames
        return
    t0 = micropython.mem_total()
    _thirteen_locals(1)
    spilled = micropython.mem_total() - t0
    micropython.heap_lock()
    try:
        r = _thirteen_locals(1)  # no MemoryError: the frame falls back to the C stack
    finally:
        micropython.heap_unlock()
    assert r == 91 and spilled > 0, spilled


def test_heap_lock_catches_an_allocation():
    """The detector works: a list built inside the lock raises (MicroPython only)."""
    if not ON_MICROPYTHON:
        # CPython: heap_lock is the shim's no-op by design; the proof runs under micropython
        assert getattr(micropython, "ROPEMON_SHIM", False)
        return
    caught = False
    micropython.heap_lock()
    try:
        x = [1, 2, 3]
    except MemoryError:
        caught = True
    micropython.heap_unlock()
    assert caught
