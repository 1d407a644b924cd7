"""The fleet consumer takes only what it can account for: a message past its size or metric
limits, one that is not Sparkplug B or is cut short, is refused whole, counted per reason and
logged (the first of a reason at once, then at most one line per reason per REFUSE_LOG_S with
the count); its metric-name cache is bounded and a message of many new names blinds nothing
after it."""
from __future__ import annotations

import logging
import random
import re
import time

import pytest

pytest.importorskip("paho.mqtt")

from ropemon.station.mqtt import fleet as fleet_mod  # noqa: E402
from ropemon.station.mqtt import sparkplug as sp  # noqa: E402
from scada_rig import wait  # noqa: E402
from test_fleet_refusals import ddata, put, rig, stop, stored  # noqa: E402

LOGGER = "ropemon.station.mqtt.fleet"


def names_message(n: int, seq: int = 1) -> bytes:
    """A DDATA of n distinct metric names (by name, as a DBIRTH or a host may send them)."""
    p = sp.payload(seq)
    for k in range(n):
        sp.add_metric(p, f"junk/{k}", sp.DOUBLE, 1.0, p.timestamp)
    return p.SerializeToString()


def reasons(fleet) -> dict[str, int]:
    return dict(fleet.stats["refused_by_reason"])


def test_100001_names_in_one_message_are_refused_and_the_frames_after_it_stored(tmp_path, caplog):
    """One message of 100,001 distinct names used to fill the name cache, so that every later
    frame's names were skipped unseen: 0 of the next 240 written, nothing refused."""
    fleet, acks = rig(tmp_path)
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        put(fleet, 1, "edge", names_message(100_001))
        for k in range(240):
            put(fleet, 2 + k, "edge", ddata(1 + k % 2, 2 + k, 1 + k))
        fleet._writer.start()
        wait(lambda: len(acks) == 241, 20, "every message acknowledged")
    assert acks == list(range(1, 242))
    assert len(stored(tmp_path)) == 240                       # none blinded
    assert fleet.stats["refused_messages"] == 1
    assert fleet.stats["name_cache_cleared"] == 0             # never decoded: its names never cached
    assert reasons(fleet) == {"too large": 1}
    assert len(fleet._names) <= fleet_mod.NAME_CACHE
    assert "too large" in caplog.text and "spBv1.0/g/DDATA/edge/h0" in caplog.text
    stop(fleet)


def test_the_name_cache_is_bounded_and_a_new_name_past_it_is_still_written(tmp_path):
    """Many messages within the limits, each of new names: the cache never grows past NAME_CACHE;
    a frame of names never seen before, after it filled, is written (the cache is emptied and
    starts again: it only saves parsing names, it decides nothing)."""
    fleet, acks = rig(tmp_path)
    per = fleet_mod.MAX_METRICS
    n_msgs = 3 * fleet_mod.NAME_CACHE // per
    for k in range(n_msgs):
        p = sp.payload(k)
        for j in range(per):                 # names of the tension pattern, the ones that are parsed
            i = k * per + j
            sp.add_metric(p, f"node{i % 256}/rope{1 + i // 256 % 255}/tension", sp.DOUBLE, 1.0, p.timestamp)
        put(fleet, 1 + k, "junk-edge", p.SerializeToString())
    sizes = []
    orig = fleet.rows_of
    fleet.rows_of = lambda topic, payload: (rows := orig(topic, payload), sizes.append(len(fleet._names)))[0]
    put(fleet, 1000, "edge", ddata(77, 1000, 5))              # node77's names: not among the last ones cached
    fleet._writer.start()
    wait(lambda: len(acks) == n_msgs + 1, 20, "every message acknowledged")
    assert max(sizes) <= fleet_mod.NAME_CACHE
    assert fleet.stats["name_cache_cleared"] >= 2
    assert ("edge", 77, 1, 5, 12.5) in stored(tmp_path)
    assert fleet.stats["refused_messages"] == 0
    stop(fleet)


def test_limits_on_size_metrics_and_topic_are_enforced_and_counted(tmp_path, caplog):
    fleet, acks = rig(tmp_path)
    big = sp.payload(1)
    sp.add_metric(big, "node1/standing_status", sp.STRING, "x" * (fleet_mod.MAX_PAYLOAD + 1), big.timestamp)
    many = sp.payload(2)
    for k in range(fleet_mod.MAX_METRICS + 1):
        sp.add_metric(many, None, sp.DOUBLE, 1.0, many.timestamp, alias=k + 1)   # a few bytes each: small
    assert len(many.SerializeToString()) < fleet_mod.MAX_PAYLOAD
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        put(fleet, 1, "edge", big.SerializeToString())
        put(fleet, 2, "edge", many.SerializeToString())
        fleet._queue.put((fleet._session, 3, 1, "spBv1.0/g/DDATA", ddata(1, 3, 3)))          # no edge node
        fleet._queue.put((fleet._session, 4, 1, "spBv1.0/g/NOPE/edge/h0", ddata(1, 4, 4)))   # no such type
        fleet._queue.put((fleet._session, 5, 1, "spBv1.0/STATE/scada", b'{"online": true, "timestamp": 1}'))
        put(fleet, 6, "edge", ddata(1, 6, 6))
        fleet._writer.start()
        wait(lambda: acks == [1, 2, 3, 4, 5, 6], 10, "every message acknowledged")
    assert [r[3] for r in stored(tmp_path)] == [6]
    assert reasons(fleet) == {"too large": 1, "too many metrics": 1, "topic": 2}   # a STATE is not data
    assert fleet.stats["refused_messages"] == 4
    stop(fleet)


def test_900_undecodable_and_truncated_payloads_are_counted_by_reason_and_logged_sparingly(
        tmp_path, caplog, monkeypatch):
    """900 payloads of random bytes and of real births and data cut short used to leave
    refused_messages at 0, with no log line."""
    monkeypatch.setattr(fleet_mod, "REFUSE_LOG_S", 1.0)
    rnd = random.Random(35)
    bad = [bytes(rnd.randrange(256) for _ in range(rnd.randrange(1, 200))) for _ in range(450)]
    birth = sp.payload(0)
    for k, (name, datatype, unit) in enumerate(sp.hoist_metrics([1])):
        sp.add_metric(birth, name, datatype, None, birth.timestamp, unit=unit, alias=k + 1)
    whole = [birth.SerializeToString(), ddata(1, 1, 1)]
    for k in range(450):
        data = whole[k % 2]
        bad.append(data[:rnd.randrange(0, len(data) - 1)])      # cut short by at least a byte
    fleet, acks = rig(tmp_path)
    for mid, data in enumerate(bad, start=1):
        kind = "DBIRTH" if mid > 450 and mid % 2 == 1 else "DDATA"
        fleet._queue.put((fleet._session, mid, 1, f"spBv1.0/g/{kind}/edge/h0", data))
    put(fleet, 901, "edge", ddata(1, 901, 7))
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        fleet._writer.start()
        wait(lambda: len(acks) == 901, 20, "every message acknowledged")
        assert fleet.stats["refused_messages"] == 900
        got = reasons(fleet)
        assert sum(got.values()) == 900
        assert set(got) == {"undecodable", "no seq"} and min(got.values()) > 10
        assert fleet.stats["held"] == 0 and [r[3] for r in stored(tmp_path)] == [7]
        lines = [r.getMessage() for r in caplog.records if "not written" in r.getMessage()]
        assert len(lines) <= 2 * 2                             # the first of each reason, a summary at most
        time.sleep(fleet_mod.REFUSE_LOG_S + 0.5)               # then the rest of the count, within the period
    said: dict[str, int] = {}
    for r in caplog.records:
        m = re.search(r"\((undecodable|no seq)\).*?(\d+) since the last line", r.getMessage())
        if m:
            said[m.group(1)] = said.get(m.group(1), 0) + int(m.group(2))
    assert said == got                                        # every refusal in some line's count
    stop(fleet)


def test_the_aliases_kept_and_the_held_ddata_are_bounded_in_bytes(tmp_path, monkeypatch):
    """DBIRTHs of ever new devices cannot fill the memory with aliases: past BIRTH_BYTES a new
    device's DBIRTH is refused, counted ("too many births"), while a rebirth of a device known
    is taken and an edge node's NBIRTH frees its devices' share; held DDATA are dropped, oldest
    first and counted, past HOLD_BYTES."""
    from test_fleet_held import EDGE, GROUP, dbirth, nbirth
    from test_fleet_held import ddata as alias_ddata
    size = len(dbirth("h0", 1))
    monkeypatch.setattr(fleet_mod, "BIRTH_BYTES", 3 * size)
    monkeypatch.setattr(fleet_mod, "HOLD_BYTES", 5 * len(alias_ddata("h0", 1, 1)))
    fleet, _ = rig(tmp_path)
    for k in range(5):
        fleet.rows_of(sp.topic(GROUP, "DBIRTH", "junk", f"d{k}"), dbirth("h0", k))
    assert reasons(fleet) == {"too many births": 2} and fleet.birth_bytes == 3 * size
    fleet.rows_of(sp.topic(GROUP, "DBIRTH", "junk", "d0"), dbirth("h0", 9))    # a rebirth: replaces its own
    assert reasons(fleet) == {"too many births": 2}
    fleet.rows_of(sp.topic(GROUP, "NBIRTH", "junk"), nbirth(1))               # a new session: frees them
    assert fleet.birth_bytes == 0
    fleet.rows_of(sp.topic(GROUP, "NBIRTH", EDGE), nbirth(1))
    fleet.rows_of(sp.topic(GROUP, "DBIRTH", EDGE, "h0"), dbirth("h0", 1))
    assert fleet.rows_of(sp.topic(GROUP, "DDATA", EDGE, "h0"), alias_ddata("h0", 2, 1))   # named: its rows
    for k in range(8):                                                         # h1's aliases unknown: held
        fleet.rows_of(sp.topic(GROUP, "DDATA", EDGE, "h1"), alias_ddata("h1", 3 + k, k))
    assert fleet.held_count == 5 and fleet.stats["dropped"] == 3
    assert fleet.held_bytes == sum(len(item[2]) for q in fleet.held.values() for item in q)
    fleet.historian.close()
