"""The boot frees the config validator before the node's code is loaded:
ropenode.config is imported, the config loaded and parsed, the module released
(config.release) and collected, and only then is the Node built from the
Config, as hal_board._boot does (the boot peak never holds both codes).

Loaded from a .py or .mpy file (not frozen) the validator's bytecode is ~11 KB
of RAM that the node needs at boot only. Under the real MicroPython
(tests/run_micropython.py) gc.mem_alloc must drop by several KB with the
Config still alive (its class has no methods, so it pins none of config.py),
and the node built from it after the release must sample and frame. Under
CPython (pytest) only the module bookkeeping and the node are checked (no
gc.mem_alloc), and the module is put back afterwards: other test files hold
names from it. (This file imports ropenode.node up front; the bench,
`ropemon bench firmware`, measures the boot order's peak.)
"""
import array
import gc
import sys

import json
import os
import random

from firmware_rig import find_file, node_doc

from ropenode import layout
from ropenode.node import K, Node

ON_MICROPYTHON = sys.implementation.name == "micropython"
# The validator compiled from source frees 12.3-12.5 KB on the unix port (64-bit), 9.4-9.5 KB
# on the 32-bit builds (i386, Thumb-2) and 10.3-10.7 KB on the WebAssembly port; from .mpy
# a little less. Pinned by any reference (a method of Config, a ConfigError kept) it frees ~0.
MIN_FREED = 8192
MID = 30000       # mid-scale counts for pressure and displacement (as test_node.py)


def _mem():
    """Heap in use (0 under CPython). Read right after a yield of a test's steps: the
    driver has collected in between, from its own level (no frame of the test or of the
    release on the stack, as hal_board.run collects once _boot has returned; on the
    WebAssembly port only such a collection frees anything, tests/run_micropython.py)."""
    return gc.mem_alloc() if ON_MICROPYTHON else 0


def _drive(steps):
    """A test's steps: under MicroPython, the generator for the driver to run (it collects
    at each yield); under CPython (pytest), run here."""
    if ON_MICROPYTHON:
        return steps
    for _ in steps:
        gc.collect()
    return None


def _load_only(path):
    """hal_board._load_config up to the release: (cfg, node_id, key, reason). ropenode.config
    stays loaded (in sys.modules); no frame of the caller holds it."""
    from ropenode import config

    return config.load_for_boot(path)


def _release():
    from ropenode import config

    config.release()


def _load(path):
    """hal_board._load_config (no `machine` here): load and validate, then release the module."""
    r = _load_only(path)
    _release()
    return r


def _boot(path, out):
    """Steps (a generator): load, collect, release, collect, then build the Node from the
    Config, as hal_board._boot does; fills out with node, ropes, reason, freed (the heap the
    release freed, the Config still alive; 0 under CPython), cfg."""
    cfg, node_id, key, reason = _load_only(path)
    yield  # collected: ropenode.config and the Config alive
    before = _mem()
    _release()
    yield  # collected once the releasing function has returned, as hal_board._boot collects
    after = _mem()
    assert "ropenode.config" not in sys.modules  # released before the Node is built
    out["node"] = Node(cfg, node_id, key)
    out["ropes"] = 4 if cfg is None else cfg.ropes
    out["reason"] = reason
    out["freed"] = before - after
    if ON_MICROPYTHON:
        print("freed by the config release:", before - after, "B")
    out["cfg"] = cfg


def _saved():
    """CPython: the config module and the package attribute, to put back (None under MicroPython:
    keeping them would defeat the collection)."""
    if ON_MICROPYTHON:
        return None
    import ropenode
    from ropenode import config
    return config, ropenode


def _restore(saved):
    if saved is not None:
        config, pkg = saved
        sys.modules["ropenode.config"] = config
        pkg.config = config


def _samples_and_frames(node, ropes, count):
    rec = array.array("H", [MID] * ropes + [MID] * ropes + [60000, 0xFFFF, 0, 0])
    buf = bytearray(layout.MAX_WIRE_LEN)
    frames = 0
    for k in range(count):
        rec[2 * ropes + 2] = (k * 10) & 0xFFFF
        if node.sample(rec):
            n = node.frame_into(buf)
            assert 0 < n <= layout.MAX_WIRE_LEN and buf[0] == 0 and buf[n - 1] == 0, n
            frames += 1
    return frames


def test_boot_releases_config_and_the_node_still_samples():
    return _drive(_boot_releases_config_and_the_node_still_samples())


def _boot_releases_config_and_the_node_still_samples():
    path = find_file("firmware/node.json")
    saved = _saved()
    try:
        b = {}
        yield from _boot(path, b)
        node, ropes, reason, freed, cfg = b["node"], b["ropes"], b["reason"], b["freed"], b["cfg"]
        assert "ropenode.config" not in sys.modules
        import ropenode
        assert not hasattr(ropenode, "config")
        if ON_MICROPYTHON:
            assert freed >= MIN_FREED, freed  # with the Config still alive
        assert reason is None, reason  # firmware/node.json is valid: a compensating node
        assert cfg is not None and cfg.ropes == ropes
        assert node.S is not None and node.n == ropes
        frames = _samples_and_frames(node, ropes, 4 * node.window_len)
        assert frames == 4, frames
        t = node.rope(K.TENSION_N)
        assert len(t) == ropes and any(t), t
    finally:
        _restore(saved)


def test_config_fault_boot_releases_config_too():
    """A refused or missing /node.json: config-fault status frames, config released all the same."""
    return _drive(_config_fault_boot_releases_config_too())


def _config_fault_boot_releases_config_too():
    saved = _saved()
    try:
        b = {}
        yield from _boot("/nonexistent/node.json", b)
        node, ropes, reason, freed, cfg = b["node"], b["ropes"], b["reason"], b["freed"], b["cfg"]
        assert cfg is None and type(reason) is str and "unreadable" in reason, reason
        assert "ropenode.config" not in sys.modules
        if ON_MICROPYTHON:
            assert freed >= MIN_FREED, freed
        assert node.S is None and node.config_error is None
        assert _samples_and_frames(node, ropes, 2 * node.window_len) == 2
    finally:
        _restore(saved)


def test_refused_config_boot_keeps_only_the_reason_string():
    """A refused /node.json (CRC mismatch): the ConfigError becomes a str reason, never kept,
    so the release frees the module all the same; the frames carry the file's node id."""
    return _drive(_refused_config_boot_keeps_only_the_reason_string())


def _refused_config_boot_keeps_only_the_reason_string():
    doc = node_doc()
    doc["crc"] = (doc["crc"] + 1) & 0xFFFF
    path = "/tmp/ropemon-bootheap-%s-%08x.json" % (sys.implementation.name, random.getrandbits(32))
    with open(path, "w") as f:
        json.dump(doc, f)
    doc = None
    saved = _saved()
    try:
        b = {}
        yield from _boot(path, b)
        node, ropes, reason, freed, cfg = b["node"], b["ropes"], b["reason"], b["freed"], b["cfg"]
        assert cfg is None and type(reason) is str and "refused" in reason and "crc" in reason, reason
        assert "ropenode.config" not in sys.modules
        if ON_MICROPYTHON:
            assert freed >= MIN_FREED, freed
        assert node.S is None and node.config_error is None
        assert node.writer.node_id == node_doc()["node"]["node_id"]
        assert _samples_and_frames(node, ropes, 2 * node.window_len) == 2
    finally:
        _restore(saved)
        os.remove(path)


def test_config_class_has_no_methods():
    """A Config pins none of config.py: its class holds no functions (they would keep the
    module's globals, and so its code, alive after the release)."""
    saved = _saved()
    try:
        cfg = _load(find_file("firmware/node.json"))[0]
        cls = type(cfg)
        for name in dir(cls):
            kind = type(getattr(cls, name)).__name__
            assert kind not in ("function", "closure", "bound_method", "method", "staticmethod",
                                "classmethod", "property"), (name, kind)
    finally:
        _restore(saved)
