"""Node config: canonical form, CRC, and refusal of bad fields with the field named.

Runs under CPython (pytest) and the real MicroPython (tests/run_micropython.py).
"""
from firmware_rig import node_doc

from ropenode import config
from ropenode.crc16 import crc16


def _refused(doc):
    try:
        config.parse(doc)
    except config.ConfigError as e:
        return e.field, e.reason
    raise AssertionError("config accepted")


def _resealed(doc):
    doc["crc"] = crc16(config.canonical(doc["node"]))
    return doc


def test_crc16_check_value():
    assert crc16(b"123456789") == 0x29B1


def test_canonical_form_is_sorted_compact_and_int_only():
    assert config.canonical({"b": [1, -2], "a": {"d": 0, "c": 30}}) == b'{"a":{"c":30,"d":0},"b":[1,-2]}'
    for bad in (1.5, True, None, "x"):
        try:
            config.canonical({"k": [bad]})
        except config.ConfigError as e:
            assert e.field == "node.k[0]", e.field
        else:
            raise AssertionError("accepted %r" % (bad,))


def test_the_crc_is_taken_without_building_the_canonical_bytes():
    for d in ({"b": [1, -2], "a": {"d": 0, "c": 30}}, node_doc()["node"], {}, [], (1, (2,)),
              {"x": [[1, 2], [], {"y": -7, "z": [0]}], "w": 2**29, "big": [2**30, -2**31, 2**64 + 5]},
              {"\u00e9t\u00e9": 1, "": [], "q\"": {}}):
        assert config.canonical_crc16(d) == crc16(config.canonical(d))
    try:
        config.canonical_crc16({"k": {1: 2}})
    except config.ConfigError as e:
        assert e.field == "node.k", e.field
    else:
        raise AssertionError("accepted a key that is not a string")
    for bad in (1.5, True, None, "x"):
        try:
            config.canonical_crc16({"k": [1, {"j": bad}]})
        except config.ConfigError as e:
            assert e.field == "node.k[1].j", e.field
        else:
            raise AssertionError("accepted %r" % (bad,))


def test_shipped_config_parses():
    c = config.parse(node_doc())
    assert c.ropes == 4 and c.sample_hz == 200 and c.window == 20
    assert len(c.key) == 16


def test_crc_mismatch_refused():
    doc = node_doc()
    doc["node"]["node_id"] = (doc["node"]["node_id"] + 1) & 0xFF  # not resealed
    f, r = _refused(doc)
    assert f == "crc" and "mismatch" in r


def test_unknown_schema_refused():
    doc = node_doc()
    doc["schema"] = 2
    assert _refused(doc)[0] == "schema"


def test_wrong_field_refused_with_its_name():
    cases = (
        (("pressure", 2, "fault_hi_counts"), 70000, "node.pressure[2].fault_hi_counts", "out of range"),
        (("ropes",), 5, "node.ropes", "out of range"),
        (("friction", "fs_n", "at_0"), 40000, "node.friction.fs_n.at_0", "out of range"),
        (("velocity", "alpha_q14"), 0, "node.velocity.alpha_q14", "out of range"),
        (("frame_hz",), 7, "node.frame_hz", "multiple"),
        (("shaft", "marks_mm"), [5, 3], "node.shaft.marks_mm[1]", "ascending"),
        (("displacement", 1, "counts_lo"), "9600", "node.displacement[1].counts_lo", "integer"),
    )
    for path, value, field, why in cases:
        doc = node_doc()
        d = doc["node"]
        for p in path[:-1]:
            d = d[p]
        d[path[-1]] = value
        try:
            _resealed(doc)
        except config.ConfigError as e:  # canonical refuses non-ints itself
            assert e.field == field, (e.field, field)
            continue
        f, r = _refused(doc)
        assert f == field and why in r, (f, r, field)


def test_missing_field_refused_with_its_name():
    doc = node_doc()
    del doc["node"]["loss"]["temps_cc"]
    f, r = _refused(_resealed(doc))
    assert f == "node.loss.temps_cc" and r == "missing"


def test_friction_out_of_range_at_top_pressure_refused():
    doc = node_doc()
    doc["node"]["friction"]["fs_n"]["slope_mul"] = 30000  # Fs beyond 32767 N at p_kpa_max
    f, r = _refused(_resealed(doc))
    assert f == "node.friction.fs_n" and "kPa" in r


def test_loss_table_entries_refused_with_their_full_path():
    cases = ((("v_um_s", 1, 2), 1 << 20, "node.loss.v_um_s[1][2]", "out of range"),
             (("v_um_s", 0, 0), 5, "node.loss.v_um_s[0][0]", "must be 0"),
             (("force_n", 2, 0, 3), 1 << 17, "node.loss.force_n[2][0][3]", "out of range"),
             (("force_n", 3, 0, 0), 7, "node.loss.force_n[3][0][0]", "must be 0"),
             (("force_n", 1, 0), [0], "node.loss.force_n[1][0]", "length"))
    for path, value, field, why in cases:
        doc = node_doc()
        d = doc["node"]["loss"]
        for p in path[:-1]:
            d = d[p]
        d[path[-1]] = value
        f, r = _refused(_resealed(doc))
        assert f == field and why in r, (f, r, field)


def test_config_tables_name_every_field_once():
    """The validation tables are parsed at boot: every row is a name and int bounds lo <= hi."""
    seen = set()
    for text, width in ((config._FIELDS, 3), (config._PRESSURE, 3), (config._DISPLACEMENT, 3),
                        (config._LINEAR, 4)):
        rows = config._table(text)
        assert rows
        for row in rows:
            assert len(row) == width and row[1] <= row[2], row
            key = (text, row[0].split(".")[-1])
            assert key not in seen, row
            seen.add(key)
