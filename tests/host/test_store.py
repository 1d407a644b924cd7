"""SQLite store: round trip, trips, events, CSV export, restart, and SIGKILL durability."""
from __future__ import annotations

import csv
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from host_rig import frame_set
from ropemon.station.alarms import AlarmEngine
from ropemon.station.decoder import StreamDecoder
from ropemon.station.protocol import encode_frame
from ropemon.station.store import SCHEMA_VERSION, Store, StoreError

HOST = Path(__file__).resolve().parents[2] / "host"


def decoded(count=30, seed=1):
    return StreamDecoder().feed(b"".join(w for _, w in frame_set(seed, count, keyed=False)))


def test_frames_round_trip(tmp_path):
    frames = decoded()
    with Store(tmp_path / "a.db") as s:
        for i, f in enumerate(frames):
            s.add_frame("pithead", f, 100.0 + i)
    with Store(tmp_path / "a.db") as s:
        back = s.frames()
        assert [b.frame for b in back] == frames
        assert [b.rx_time for b in back] == [100.0 + i for i in range(len(frames))]
        assert {b.receiver for b in back} == {"pithead"}
        node1 = s.frames(node=1, t0=105, t1=120)
        assert node1 and all(b.frame.node == 1 and 105 <= b.rx_time <= 120 for b in node1)


def test_restart_continues_the_same_database(tmp_path):
    p = tmp_path / "a.db"
    frames = decoded(10)
    with Store(p) as s:
        ids1 = [s.add_frame("a", f, i) for i, f in enumerate(frames[:5])]
    with Store(p) as s:
        assert s.committed_frames == 5
        ids2 = [s.add_frame("a", f, 5 + i) for i, f in enumerate(frames[5:])]
        assert min(ids2) > max(ids1)
        assert [b.frame for b in s.frames()] == frames


def test_newer_schema_and_foreign_files_are_refused(tmp_path):
    p = tmp_path / "a.db"
    Store(p).close()
    db = sqlite3.connect(p)
    db.execute("UPDATE meta SET value=? WHERE key='schema_version'", (str(SCHEMA_VERSION + 1),))
    db.commit()
    db.close()
    with pytest.raises(StoreError, match="newer"):
        Store(p)
    junk = tmp_path / "junk.db"
    junk.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(StoreError, match="not a usable"):
        Store(junk)


def test_trips_from_speed(tmp_path):
    # rest 5 s, move down 10 s, rest 5 s, move up 10 s, rest 5 s; 10 frames/s
    plan = [(0, 50), (10000, 100), (0, 50), (-10000, 100), (0, 50)]
    with Store(tmp_path / "a.db", trip_rest_s=3.0) as s:
        seq, t, depth = 0, 0.0, 0
        for speed, n in plan:
            for _ in range(n):
                _, w = encode_frame(node=1, seq=seq, ropes=[(5000, 4990, 5010, 6000)] * 4,
                                    speed_mm_s=speed, depth_mm=depth)
                s.add_frame("a", StreamDecoder().feed(w)[0], t)
                seq += 1
                t += 0.1
                depth += speed // 10
        trips = s.trips()
        assert len(trips) == 2
        down, up = trips
        assert down.start_time == pytest.approx(5.0) and down.end_time == pytest.approx(15.0)
        assert down.start_depth_mm == 0 and down.end_depth_mm == 100_000
        assert up.end_depth_mm == 0
        inside = s.frames(trip=down)
        assert len(inside) == 101 and all(b.frame.speed_mm_s == 10000 for b in inside[:-1])


def test_events_link_stats_and_csv_export(tmp_path):
    eng = AlarmEngine()
    frames = []
    for i in range(10):
        _, w = encode_frame(node=1, seq=i, ropes=[(5000, 0, 0, 0)] * 3 + [(7000, 0, 0, 0)])
        frames.append(StreamDecoder().feed(w)[0])
    with Store(tmp_path / "a.db") as s:
        for i, f in enumerate(frames):
            s.add_frame("a", f, i * 0.1)
            for e in eng.update(f, i * 0.1):
                s.add_event(e)
        s.add_link_stats(1.0, "a", {"frames_ok": 10, "crc_fail": 2}, node=1, merged={"share": 0.9, "lost": 1})
        paths = s.export_csv(tmp_path / "csv")
        assert s.events()[0]["alarm"] == "deviation:n1:r3"
    names = sorted(p.name for p in paths)
    assert names == ["events.csv", "frames.csv", "link_stats.csv", "trips.csv"]
    rows = list(csv.DictReader((tmp_path / "csv" / "frames.csv").open()))
    assert len(rows) == 10 and rows[3]["seq"] == "3" and rows[3]["r4_mean_dan"] == "7000"   # rope 4 of the cage
    assert rows[3]["rx_time_utc"] == "1970-01-01T00:00:00.300Z"
    ev = list(csv.DictReader((tmp_path / "csv" / "events.csv").open()))
    assert ev[0]["action"] == "raise" and float(ev[0]["value"]) > 0.1
    assert ev[0]["rope"] == "4" and ev[0]["alarm"] == "deviation:n1:r3"
    ls = list(csv.DictReader((tmp_path / "csv" / "link_stats.csv").open()))
    assert ls[0]["crc_fail"] == "2" and ls[0]["share"] == "0.9"



def test_link_stats_keep_rewound_and_duplicate_counts(tmp_path):
    from ropemon.station.decoder import DecodeCounts
    counts = DecodeCounts(frames_ok=9, replayed=4, rewound=3, duplicate=2)
    with Store(tmp_path / "a.db") as s:
        s.add_link_stats(1.0, "pithead", counts.as_dict())
        row = s.link_stats()[0]
    assert (row["replayed"], row["rewound"], row["duplicate"], row["duplicates"]) == (4, 3, 2, None)
    # A file written before these columns existed (schema 1, pre-release) gets them on open.
    old = tmp_path / "old.db"
    with Store(old) as s:
        s.add_link_stats(1.0, "pithead", {"frames_ok": 5})
    db = sqlite3.connect(old)
    db.execute("ALTER TABLE link_stats DROP COLUMN rewound")
    db.execute("ALTER TABLE link_stats DROP COLUMN duplicate")
    db.commit()
    db.close()
    with Store(old) as s:
        s.add_link_stats(2.0, "pithead", counts.as_dict())
        rows = s.link_stats()
    assert [(r["frames_ok"], r["rewound"], r["duplicate"]) for r in rows] == [(5, None, None), (9, 3, 2)]


WRITER = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {host!r})
    from ropemon.firmware import install_shim; install_shim()
    from ropemon.station.decoder import StreamDecoder
    from ropemon.station.protocol import encode_frame
    from ropemon.station.store import Store
    s = Store(sys.argv[1], batch_frames=7, max_latency_s=10)
    start = int(sys.argv[2])
    queued = []
    for seq in range(start, start + 100000):
        _, w = encode_frame(node=1, seq=seq, ropes=[(seq % 30000, 0, 0, 0)] * 4)
        s.add_frame("a", StreamDecoder().feed(w)[0], time.time())
        queued.append(seq)
        if s.pending_frames == 0:          # add_frame committed the batch: report it stored
            print(" ".join(map(str, queued)), flush=True)
            queued = []
""")


def test_sigkill_loses_no_frame_reported_stored(tmp_path):
    db = tmp_path / "k.db"
    script = tmp_path / "writer.py"
    script.write_text(WRITER.format(host=str(HOST)))
    reported: set[int] = set()
    start = 0
    for round_ in range(3):  # kill, restart on the same file, kill again
        proc = subprocess.Popen([sys.executable, str(script), str(db), str(start)],
                                stdout=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 20
        lines = 0
        while lines < 40 + 17 * round_ and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            reported.update(int(x) for x in line.split())
            lines += 1
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        assert proc.returncode == -signal.SIGKILL
        assert lines > 0
        start = max(reported) + 1000
    with Store(db) as s:
        stored = {b.frame.seq for b in s.frames()}
    assert reported <= stored
    assert len(reported) >= 3 * 40 * 7


def test_report_and_export_read_a_write_protected_log(tmp_path):
    """A log copied off the hoist-room PC, read-only, in a read-only folder: readable, never written."""
    import os
    import stat
    import subprocess
    import sys

    folder = tmp_path / "copy"
    folder.mkdir()
    db = folder / "hoist.db"
    with Store(db) as s:
        for i in range(5):
            _, w = encode_frame(node=1, seq=i, speed_mm_s=0, ropes=[(5000, 0, 0, 0)] * 4)
            s.add_frame("a", StreamDecoder().feed(w)[0], float(i))
    for p in folder.iterdir():
        if p.name != "hoist.db":
            p.unlink()                                   # no -wal/-shm left behind
    before = db.read_bytes()
    db.chmod(stat.S_IRUSR)
    folder.chmod(stat.S_IRUSR | stat.S_IXUSR)
    try:
        with Store(db, readonly=True) as s:
            assert len(s.frames()) == 5 and s.events() == []
        out = tmp_path / "csv"
        r = subprocess.run([sys.executable, "-m", "ropemon.cli", "export", str(db), "--out", str(out)],
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        assert len((out / "frames.csv").read_text().splitlines()) == 6
    finally:
        folder.chmod(stat.S_IRWXU)
        db.chmod(stat.S_IRUSR | stat.S_IWUSR)
    assert db.read_bytes() == before                     # the log itself is never written
    if os.geteuid() != 0:          # root may create SQLite's -shm beside it; anyone else cannot
        assert sorted(p.name for p in folder.iterdir()) == ["hoist.db"]


def test_a_log_sqlite_cannot_open_read_only_in_wal_is_opened_immutable(tmp_path, monkeypatch):
    """In a folder it cannot write, SQLite cannot make a WAL log's -shm and mode=ro fails (as a
    non-root user; root can always write, so the refusal is stood in for here)."""
    import ropemon.station.store as st

    db = tmp_path / "hoist.db"
    with Store(db):
        pass
    real = sqlite3.connect
    uris = []

    def connect(database, *a, **kw):
        uris.append(database)
        if "immutable" not in database:
            raise sqlite3.OperationalError("unable to open database file")
        return real(database, *a, **kw)

    monkeypatch.setattr(st.sqlite3, "connect", connect)
    with Store(db, readonly=True) as s:
        assert s.frames() == []
    assert uris[-1].endswith("?mode=ro&immutable=1")


def _schema_1_file(path, frames):
    """A log as schema version 1 wrote it: no stroke_mask, no pos_01mm, version 1 in meta."""
    with Store(path) as s:
        for i, f in enumerate(frames):
            s.add_frame("pithead", f, 100.0 + i)
    db = sqlite3.connect(path)
    db.execute("ALTER TABLE frames DROP COLUMN stroke_mask")
    db.execute("ALTER TABLE ropes DROP COLUMN pos_01mm")
    db.execute("UPDATE meta SET value='1' WHERE key='schema_version'")
    db.commit()
    db.close()


def test_a_schema_1_log_still_opens_read_only_and_is_migrated_when_written(tmp_path):
    p = tmp_path / "old.db"
    frames = decoded(6)
    _schema_1_file(p, frames)
    with Store(p, readonly=True) as s:          # report and export on an old log: nothing written
        assert s.schema_version == 1
        assert [b.frame.ropes == f.ropes for b, f in zip(s.frames(), frames)] == [True] * 6
        s.export_csv(tmp_path / "csv")
    rows = list(csv.DictReader((tmp_path / "csv" / "frames.csv").open()))
    assert rows[0]["stroke_mask"] == "" and rows[0]["r1_pos_01mm"] == ""
    db = sqlite3.connect(p)
    assert "pos_01mm" not in {r[1] for r in db.execute("PRAGMA table_info(ropes)")}
    db.close()
    with Store(p) as s:                         # a writer migrates it: the new columns, NULL in old rows
        assert s.schema_version == SCHEMA_VERSION == 2
        s.add_frame("pithead", frames[0], 200.0)
        assert len(s.frames()) == 7
        assert s.db.execute("SELECT count(*) FROM ropes WHERE pos_01mm IS NOT NULL").fetchone()[0] == 0
        assert s.db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()[0] == "2"


def test_positions_and_the_stroke_mask_are_logged_and_exported(tmp_path):
    from ropemon.station.protocol import L, Rope
    ropes = [Rope(5000, 4990, 5010, 700, 123), Rope(5000, 4990, 5010, 700, -456),
             Rope(5000, 4990, 5010, 700, L.POS_ABSENT), Rope(5000, 4990, 5010, 700, 0)]
    _, w3 = encode_frame(node=1, seq=1, ropes=ropes, stroke_mask=0x12, status=L.ST_STROKE_LIMIT)
    _, w2 = encode_frame(node=1, seq=2, ropes=[tuple(r)[:4] for r in ropes], version=2)
    f3, f2 = StreamDecoder().feed(w3 + w2)
    assert (f3.version, f3.stroke_mask, f2.version) == (3, 0x12, 2)
    with Store(tmp_path / "a.db") as s:
        s.add_frame("a", f3, 1.0)
        s.add_frame("a", f2, 1.1)
        back = [b.frame for b in s.frames()]
        assert back == [f3, f2]                       # the positions (and the absent one) come back
        assert [r.pos_01mm for r in back[0].ropes] == [123, -456, L.POS_ABSENT, 0]
        assert s.db.execute("SELECT stroke_mask FROM frames ORDER BY id").fetchall() == [(0x12,), (None,)]
        assert s.db.execute("SELECT pos_01mm FROM ropes WHERE frame_id = 1 ORDER BY rope").fetchall() == \
            [(123,), (-456,), (None,), (0,)]
        s.export_csv(tmp_path / "csv")
    rows = list(csv.DictReader((tmp_path / "csv" / "frames.csv").open()))
    assert [rows[0][f"r{i}_pos_01mm"] for i in range(1, 5)] == ["123", "-456", "", "0"]
    assert rows[0]["stroke_mask"] == "18" and rows[1]["stroke_mask"] == ""
    assert [rows[1][f"r{i}_pos_01mm"] for i in range(1, 5)] == [""] * 4   # a version-2 frame has none
    header = next(csv.reader((tmp_path / "csv" / "frames.csv").open()))
    assert header.index("r4_raw_kpa") < header.index("stroke_mask") < header.index("r1_pos_01mm")


def _event(t, action, alarm="deviation:n1:r2", kind="deviation", node=1, rope=1, message="rope 2 deviates",
           operator=None):
    from ropemon.station.alarms import AlarmEvent
    return AlarmEvent(time_s=t, action=action, alarm=alarm, kind=kind, node=node, rope=rope, value=0.2,
                      threshold=0.1, message=message, worst=0.25, operator=operator)


def _drop_event_columns(path):
    """The events table as files written before `worst` and `operator` had it."""
    db = sqlite3.connect(path)
    db.execute("ALTER TABLE events DROP COLUMN worst")
    db.execute("ALTER TABLE events DROP COLUMN operator")
    db.commit()
    db.close()


def test_the_log_reads_of_the_faces_events(tmp_path):
    """`Store.events` and `Store.event_kinds`: the web's event log and OPC UA's event history."""
    p = tmp_path / "a.db"
    with Store(p) as s:
        s.add_event(_event(10.0, "raise"))
        s.add_event(_event(30.0, "ack", operator="alice (web)", message="acknowledged 50% now"))
        s.add_event(_event(20.0, "clear"))          # logged after, but earlier in time
        s.add_event(_event(40.0, "accept", alarm="rewound:n2", kind="link_integrity", node=2, rope=None,
                           message="accepted by bob"))
        assert [e["id"] for e in s.events()] == [1, 2, 3, 4]
        assert list(s.events()[0]) == ["id", "time_s", "action", "alarm", "kind", "node", "rope", "value",
                                       "threshold", "message", "worst", "operator"]
        assert [e["id"] for e in s.events(newest_first=True, limit=2)] == [4, 3]
        assert [e["id"] for e in s.events(by_time=True)] == [1, 3, 2, 4]
        assert [e["id"] for e in s.events(by_time=True, newest_first=True, limit=3)] == [4, 2, 3]
        assert [e["id"] for e in s.events(since=20.0, until=30.0, by_time=True)] == [3, 2]
        assert [e["id"] for e in s.events(action="clear")] == [3]
        assert [e["id"] for e in s.events(kind="link_integrity")] == [4]
        assert [e["id"] for e in s.events(node=1)] == [1, 2, 3]
        assert [e["id"] for e in s.events(text="alice")] == [2]                 # the operator
        assert [e["id"] for e in s.events(text="50%")] == [2]                   # % is a character
        assert s.events(text="5_%") == []
        assert [e["id"] for e in s.events(text="rewound")] == [4]               # the alarm id
        assert [e["id"] for e in s.events(operator_only=True)] == [2, 4]
        assert s.event_kinds() == ["deviation", "link_integrity"]
    _drop_event_columns(p)
    with Store(p, readonly=True) as s:                  # an older file, read-only: no such keys
        rows = s.events()
        assert [e["id"] for e in rows] == [1, 2, 3, 4] and not {"worst", "operator"} & set(rows[0])
        assert [e["id"] for e in s.events(text="bob")] == [4]
        assert s.events(text="alice") == []
        assert [e["id"] for e in s.events(operator_only=True)] == [2, 4]       # ack, accept
        assert [e["id"] for e in s.events(by_time=True, newest_first=True, limit=1)] == [4]
        assert s.event_kinds() == ["deviation", "link_integrity"]


def test_the_log_reads_of_the_faces_trips_and_trends(tmp_path):
    """`Store.trips(newest_first, limit)`, `trip`, `depth_span`, `frame_buckets`,
    `tension_buckets` and `nodes`, on a new file and on a schema 1 one read-only."""
    from ropemon.station.protocol import L
    plan = [(0, 50), (10000, 100), (0, 50), (-10000, 100), (0, 50)]   # rest, down 100 m, rest, up, rest
    frames, depth = [], 0
    for speed, n in plan:
        for _ in range(n):
            ropes = [(5000, 4990, 5010, 6000)] * 3 + [(L.TENSION_ABSENT, 0, 0, 0)]
            _, w = encode_frame(node=1, seq=len(frames), ropes=ropes, speed_mm_s=speed, depth_mm=depth)
            frames.append(StreamDecoder().feed(w)[0])
            depth += speed // 10
    _, w = encode_frame(node=3, seq=0, ropes=[(6000, 5990, 6010, 7000)] * 2, depth_mm=5)
    frames.append(StreamDecoder().feed(w)[0])
    p = tmp_path / "a.db"
    with Store(p, trip_rest_s=3.0) as s:
        for i, f in enumerate(frames):
            s.add_frame("a", f, i * 0.1)
    old = tmp_path / "old.db"
    _schema_1_file(old, frames)                         # rx_time 100 + i
    for path, t0, dt, readonly in ((p, 0.0, 0.1, False), (old, 100.0, 1.0, True)):
        with Store(path, readonly=readonly) as s:
            down, up = s.trips()
            assert s.trips(newest_first=True) == [up, down] and s.trips(newest_first=True, limit=1) == [up]
            assert s.trips(3) == [] and s.trips(1, limit=1) == [down]
            assert s.trip(down.id) == down and s.trip(99) is None
            assert s.depth_span(1, down.first_frame_id, down.last_frame_id) == 100_000
            assert s.depth_span(1, up.last_frame_id) == 0 and s.depth_span(2, 1) == 0
            assert s.nodes() == [1, 3]
            fb = s.frame_buckets(1, t0, t0 + 1000 * dt, 100 * dt)          # 100 frames a bucket
            assert [b.bucket for b in fb] == [0, 1, 2, 3] and sum(b.frames for b in fb) == 350
            assert (fb[0].frames, fb[0].depth_mm) == (100, 12250) and fb[0].rx_time == pytest.approx(t0 + 49.5 * dt)
            assert s.frame_buckets(1, t0 + 100 * dt, t0 + 149 * dt, 100 * dt)[0].frames == 50
            tb = s.tension_buckets(1, t0, t0 + 1000 * dt, 100 * dt)
            assert [(b.bucket, b.rope) for b in tb[:4]] == [(0, 0), (0, 1), (0, 2), (1, 0)]   # rope 4: none
            assert (tb[0].mean_dan, tb[0].min_dan, tb[0].max_dan) == (5000, 4990, 5010)
            assert len(tb) == 4 * 3 and s.tension_buckets(3, t0, t0 + 1000 * dt, 100 * dt)[0].mean_dan == 6000
