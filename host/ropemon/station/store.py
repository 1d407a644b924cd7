"""SQLite log of frames, alarm events, link statistics and trips (schema: docs/storage.md).

Durability: WAL journal with synchronous=FULL. Frames are inserted into an open
transaction that is committed when `batch_frames` are pending or the oldest
pending one is `max_latency_s` old (checked on every add and by `flush()`), so
a frame is at most that late on disk. A frame counts as stored only once
`commit()`/`flush()` has returned (`committed_frames`); those survive SIGKILL
and power loss. Reopening a file continues it; a file with a newer schema is refused.
`last_seqs` and `recent_frames` give a restarted host the replay protection state
to resume from (docs/protocol.md).

One Store belongs to one thread (sqlite3 connections are not shared).
"""
from __future__ import annotations

import csv
import datetime
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from ropemon.station.nodetime import NodeClock
from ropemon.station.protocol import Frame, L, Rope

OIL_TEMP_ABSENT = L.OIL_TEMP_ABSENT

SCHEMA_VERSION = 2
#: what opening an older file adds (docs/storage.md): version -> [(table, column, type)]
_MIGRATIONS = {2: [("frames", "stroke_mask", "INTEGER"), ("ropes", "pos_01mm", "INTEGER")]}
POS_ABSENT = L.POS_ABSENT

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS frames (
    id INTEGER PRIMARY KEY,
    rx_time REAL NOT NULL,
    receiver TEXT NOT NULL,
    node INTEGER NOT NULL,
    seq INTEGER NOT NULL,
    version INTEGER NOT NULL,
    kind INTEGER NOT NULL,
    time_ms INTEGER NOT NULL,
    status INTEGER NOT NULL,
    fault_mask INTEGER NOT NULL,
    depth_mm INTEGER NOT NULL,
    speed_mm_s INTEGER NOT NULL,
    battery_mv INTEGER NOT NULL,
    oil_temp_cc INTEGER NOT NULL,
    authenticated INTEGER,
    mac BLOB NOT NULL,
    stroke_mask INTEGER
);
CREATE INDEX IF NOT EXISTS frames_node_time ON frames (node, rx_time);
CREATE INDEX IF NOT EXISTS frames_node_seq ON frames (node, seq);
CREATE TABLE IF NOT EXISTS ropes (
    frame_id INTEGER NOT NULL REFERENCES frames (id),
    rope INTEGER NOT NULL,
    mean_dan INTEGER NOT NULL,
    min_dan INTEGER NOT NULL,
    max_dan INTEGER NOT NULL,
    raw_kpa INTEGER NOT NULL,
    pos_01mm INTEGER,
    PRIMARY KEY (frame_id, rope)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY,
    time_s REAL NOT NULL,
    action TEXT NOT NULL,
    alarm TEXT NOT NULL,
    kind TEXT NOT NULL,
    node INTEGER,
    rope INTEGER,
    value REAL,
    threshold REAL,
    message TEXT NOT NULL,
    worst REAL,
    operator TEXT
);
CREATE TABLE IF NOT EXISTS link_stats (
    id INTEGER PRIMARY KEY,
    time_s REAL NOT NULL,
    receiver TEXT NOT NULL,
    node INTEGER,
    frames_ok INTEGER, crc_fail INTEGER, malformed INTEGER, mac_fail INTEGER,
    replayed INTEGER, bytes_discarded INTEGER,
    delivered INTEGER, share REAL, lost INTEGER, duplicates INTEGER,
    rewound INTEGER, duplicate INTEGER
);
CREATE TABLE IF NOT EXISTS trips (
    id INTEGER PRIMARY KEY,
    node INTEGER NOT NULL,
    start_time REAL NOT NULL,
    end_time REAL,
    start_depth_mm INTEGER NOT NULL,
    end_depth_mm INTEGER,
    first_frame_id INTEGER NOT NULL,
    last_frame_id INTEGER
);
"""

_FRAME_COLS = ("rx_time", "receiver", "node", "seq", "version", "kind", "time_ms", "status",
               "fault_mask", "depth_mm", "speed_mm_s", "battery_mv", "oil_temp_cc", "authenticated", "mac",
               "stroke_mask")
_ROPE_COLS = ("mean_dan", "min_dan", "max_dan", "raw_kpa", "pos_01mm")
_LINK_COLS = ("frames_ok", "crc_fail", "malformed", "mac_fail", "replayed", "bytes_discarded",
              "delivered", "share", "lost", "duplicates", "rewound", "duplicate")
#: link_stats columns added to schema 1 before its first release; files written
#: before that get them on open (nullable, so their old rows read as NULL).
_LINK_COLS_ADDED = ("rewound", "duplicate")
_EVENT_COLS = ("time_s", "action", "alarm", "kind", "node", "rope", "value", "threshold", "message", "worst",
               "operator")
#: events columns added to schema 1 later; files written before get them on open (NULL in old rows).
_EVENT_COLS_ADDED = {"worst": "REAL", "operator": "TEXT"}
_TRIP_SQL = "id, node, start_time, end_time, start_depth_mm, end_depth_mm, first_frame_id, last_frame_id"


def _open_readonly(path: str) -> sqlite3.Connection:
    """A read-only connection: the file is never written (report and export on a copied or
    write-protected log). In WAL mode SQLite still wants the -shm file; where it cannot make
    it (a read-only folder), the file is opened as immutable (no writer may run then)."""
    uri = Path(path).resolve().as_uri()
    last: Exception | None = None
    for query in ("?mode=ro", "?mode=ro&immutable=1"):
        try:
            db = sqlite3.connect(uri + query, uri=True, isolation_level=None)
            db.execute("SELECT count(*) FROM sqlite_master").fetchone()
            return db
        except sqlite3.DatabaseError as e:
            last = e
    raise StoreError(f"{path}: cannot open read-only ({last})")


def _with_utc(row: list, *cols) -> list:
    """`row` with an ISO-8601 UTC column after each time column (given by name in a header
    row, by index in a data row; an empty time stays empty)."""
    if cols and isinstance(cols[0], str):
        at = {row.index(c) for c in cols}
        return [x for k, name in enumerate(row) for x in ((name, f"{name}_utc") if k in at else (name,))]
    out = []
    for k, v in enumerate(row):
        out.append(v)
        if k in cols:
            out.append("" if v is None else datetime.datetime.fromtimestamp(v, datetime.timezone.utc)
                       .isoformat(timespec="milliseconds").replace("+00:00", "Z"))
    return out


class StoreError(RuntimeError):
    pass


def _pos(r: Rope) -> int | None:
    """A rope record's piston position for the log (0.1 mm), None where the frame has none."""
    return None if r.pos_01mm == POS_ABSENT else r.pos_01mm


@dataclass(frozen=True)
class StoredFrame:
    id: int
    rx_time: float
    receiver: str
    frame: Frame


@dataclass(frozen=True)
class StoredTrip:
    """A trip as the log holds it (`Store.trips`): its frames are the ids between first and last."""

    id: int
    node: int
    start_time: float
    end_time: float | None      # None: still moving when last seen
    start_depth_mm: int
    end_depth_mm: int | None
    first_frame_id: int
    last_frame_id: int | None


class FrameBucket(NamedTuple):
    """One time bucket of a node's frames (`Store.frame_buckets`)."""
    bucket: int          # (rx_time - t0) // bucket_s
    rx_time: float       # the mean rx_time of its frames
    depth_mm: float      # their mean depth
    frames: int          # how many


class TensionBucket(NamedTuple):
    """One rope's tension in one time bucket (`Store.tension_buckets`), in daN."""
    bucket: int
    rope: int            # from 0
    mean_dan: float      # the mean of the frames' window means
    min_dan: int         # the lowest window minimum
    max_dan: int         # the highest window maximum


class _TripDetector:
    """Motion between two rests, from frame speed. A trip starts on sustained motion: consecutive
    frames with |speed| >= moving in one direction that cover start_m (their speed times the time
    between them); it starts at the first of them. A frame or a few with an encoder pulse (the
    ropes stretching while the cage is loaded at rest) do not start one. It ends after rest_s
    with |speed| below moving, at the first of those frames."""

    def __init__(self, moving_mm_s: int, rest_s: float, start_m: float = 0.5):
        self.moving_mm_s = moving_mm_s
        self.rest_s = rest_s
        self.start_m = start_m
        self.open: dict[int, int] = {}         # node -> trip id
        self.rest_since: dict[int, tuple[float, int, int]] = {}  # node -> (time, depth, frame id)
        # node -> (time, depth, frame id) of the run's first frame, its direction, metres covered, last time
        self.run: dict[int, tuple[float, int, int, int, float, float]] = {}


class Store:
    def __init__(self, path: str | Path, *, batch_frames: int = 50, max_latency_s: float = 0.5,
                 synchronous: str = "FULL", trip_moving_mm_s: int = 100, trip_rest_s: float = 3.0,
                 trip_start_m: float = 0.5, readonly: bool = False):
        self.path = str(path)
        self.batch_frames = batch_frames
        self.max_latency_s = max_latency_s
        self.readonly = readonly
        if readonly:
            self.db = _open_readonly(self.path)
        else:
            try:
                self.db = sqlite3.connect(self.path, isolation_level=None)
                self.db.execute("PRAGMA journal_mode=WAL")
                self.db.execute(f"PRAGMA synchronous={synchronous}")
                self.db.executescript(_SCHEMA)
            except sqlite3.DatabaseError as e:
                raise StoreError(f"{self.path}: not a usable ropemon database ({e})") from None
        try:
            row = self.db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
        except sqlite3.DatabaseError as e:
            raise StoreError(f"{self.path}: not a usable ropemon database ({e})") from None
        if row is None and readonly:
            raise StoreError(f"{self.path}: not a ropemon database (no schema version)")
        if row is None:
            self.db.execute("INSERT INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
            self.db.execute("INSERT INTO meta VALUES ('created', ?)", (str(time.time()),))
        elif int(row[0]) > SCHEMA_VERSION:
            raise StoreError(f"{self.path}: schema version {row[0]} is newer than this ropemon ({SCHEMA_VERSION})")
        self.schema_version = SCHEMA_VERSION if row is None else int(row[0])
        if not readonly and self.schema_version < SCHEMA_VERSION:
            self._migrate()
        # a read-only older file: its missing columns read as NULL
        self._frame_sql = ",".join(self._cols("frames", _FRAME_COLS))
        self._rope_sql = ",".join(self._cols("ropes", _ROPE_COLS))
        if not readonly:
            have = {r[1] for r in self.db.execute("PRAGMA table_info(link_stats)")}
            for col in _LINK_COLS_ADDED:
                if col not in have:
                    self.db.execute(f"ALTER TABLE link_stats ADD COLUMN {col} INTEGER")
            have = {r[1] for r in self.db.execute("PRAGMA table_info(events)")}
            for col, typ in _EVENT_COLS_ADDED.items():
                if col not in have:
                    self.db.execute(f"ALTER TABLE events ADD COLUMN {col} {typ}")
        # the events columns this file has (a read-only older one may lack worst, operator)
        have = {r[1] for r in self.db.execute("PRAGMA table_info(events)")}
        self._event_cols = ("id", *(c for c in _EVENT_COLS if c in have))
        self._trip = _TripDetector(trip_moving_mm_s, trip_rest_s, trip_start_m)
        for tid, node in self.db.execute("SELECT id, node FROM trips WHERE end_time IS NULL"):
            self._trip.open[node] = tid
        self._pending = 0
        self._pending_since: float | None = None
        self.committed_frames = self.db.execute("SELECT count(*) FROM frames").fetchone()[0]

    def _cols(self, table: str, cols: tuple[str, ...]) -> list[str]:
        have = {r[1] for r in self.db.execute(f"PRAGMA table_info({table})")}
        return [c if c in have else f"NULL AS {c}" for c in cols]

    def _migrate(self) -> None:
        """Bring a file of an older schema version to this one, in one transaction: the columns
        each later version added (NULL in the older rows), then the new version number."""
        self.db.execute("BEGIN IMMEDIATE")
        try:
            for version in range(self.schema_version + 1, SCHEMA_VERSION + 1):
                for table, col, typ in _MIGRATIONS.get(version, ()):
                    have = {r[1] for r in self.db.execute(f"PRAGMA table_info({table})")}
                    if col not in have:
                        self.db.execute(f"ALTER TABLE {table} ADD COLUMN {col} {typ}")
            self.db.execute("UPDATE meta SET value=? WHERE key='schema_version'", (str(SCHEMA_VERSION),))
            self.db.execute("COMMIT")
        except sqlite3.Error as e:
            self.db.execute("ROLLBACK")
            raise StoreError(f"{self.path}: cannot migrate schema version {self.schema_version} to "
                             f"{SCHEMA_VERSION} ({e})") from None
        self.schema_version = SCHEMA_VERSION

    # -- writing --------------------------------------------------------------

    @property
    def pending_frames(self) -> int:
        """Frames added but not yet committed (not yet stored)."""
        return self._pending

    def _begin(self) -> None:
        if not self.db.in_transaction:
            self.db.execute("BEGIN")

    def add_frame(self, receiver: str, frame: Frame, rx_time: float) -> int:
        """Queue one (merged, first-copy) frame; returns its row id. Stored after the next commit."""
        self._begin()
        cur = self.db.execute(
            f"INSERT INTO frames ({','.join(_FRAME_COLS)}) VALUES ({','.join('?' * len(_FRAME_COLS))})",
            (rx_time, receiver, frame.node, frame.seq, frame.version, frame.kind, frame.time_ms,
             frame.status, frame.fault_mask, frame.depth_mm, frame.speed_mm_s, frame.battery_mv,
             frame.oil_temp_cc, None if frame.authenticated is None else int(frame.authenticated), frame.mac,
             frame.stroke_mask if frame.version >= 3 else None))
        fid = int(cur.lastrowid or 0)
        if frame.ropes:
            self.db.executemany(
                f"INSERT INTO ropes (frame_id, rope, {','.join(_ROPE_COLS)}) VALUES (?,?,?,?,?,?,?)",
                [(fid, i, r[0], r[1], r[2], r[3], _pos(r)) for i, r in enumerate(frame.ropes)])
        self._trip_step(frame, rx_time, fid)
        self._pending += 1
        if self._pending_since is None:
            self._pending_since = time.monotonic()
        self.flush()
        return fid

    def _trip_step(self, frame: Frame, t: float, fid: int) -> None:
        d = self._trip
        node = frame.node
        moving = abs(frame.speed_mm_s) >= d.moving_mm_s
        tid = d.open.get(node)
        if moving:
            d.rest_since.pop(node, None)
            if tid is None:
                sign = 1 if frame.speed_mm_s > 0 else -1
                run = d.run.get(node)
                if run is None or run[3] != sign:
                    run = (t, frame.depth_mm, fid, sign, 0.0, t)
                else:  # the speed is the window's mean: the distance since the run's last frame
                    run = run[:4] + (run[4] + abs(frame.speed_mm_s) / 1000 * min(max(t - run[5], 0.0), 1.0), t)
                d.run[node] = run
                if run[4] >= d.start_m:
                    cur = self.db.execute(
                        "INSERT INTO trips (node, start_time, start_depth_mm, first_frame_id) VALUES (?,?,?,?)",
                        (node, run[0], run[1], run[2]))
                    d.open[node] = int(cur.lastrowid or 0)
                    del d.run[node]
            return
        d.run.pop(node, None)
        if tid is not None:
            rest = d.rest_since.setdefault(node, (t, frame.depth_mm, fid))
            if t - rest[0] >= d.rest_s:
                self.db.execute("UPDATE trips SET end_time=?, end_depth_mm=?, last_frame_id=? WHERE id=?",
                                (rest[0], rest[1], rest[2], tid))
                del d.open[node]
                del d.rest_since[node]

    def add_event(self, event) -> None:
        """Log an AlarmEvent and commit at once (with any pending frames): alarms are rare and must not wait.
        A station event's numbers go in the value and threshold columns (`AlarmEvent.row`)."""
        self._begin()
        row = event.row()
        self.db.execute(f"INSERT INTO events ({','.join(_EVENT_COLS)}) VALUES ({','.join('?' * len(_EVENT_COLS))})",
                        tuple(row[c] for c in _EVENT_COLS))
        self.commit()

    def add_link_stats(self, time_s: float, receiver: str, counts: dict | None = None,
                       node: int | None = None, merged: dict | None = None) -> None:
        """Log a receiver's decoder counts and/or its merge figures for a node (Merger.stats()[node]["receivers"][r] + lost/duplicates)."""
        vals = dict(counts or {})
        vals.update(merged or {})
        self._begin()
        self.db.execute(
            f"INSERT INTO link_stats (time_s, receiver, node, {','.join(_LINK_COLS)}) "
            f"VALUES (?,?,?,{','.join('?' * len(_LINK_COLS))})",
            (time_s, receiver, node, *(vals.get(c) for c in _LINK_COLS)))
        if not self._pending:
            self.commit()

    def flush(self) -> int:
        """Commit if the batch is full or its latency bound is reached; return frames committed."""
        if self._pending and (self._pending >= self.batch_frames
                              or time.monotonic() - (self._pending_since or 0.0) >= self.max_latency_s):
            return self.commit()
        return 0

    def commit(self) -> int:
        """Make everything queued durable; return the number of frames it stored."""
        n = self._pending
        if self.db.in_transaction:
            self.db.execute("COMMIT")
        self._pending = 0
        self._pending_since = None
        self.committed_frames += n
        return n

    def rollback(self) -> None:
        """After a failed write (disk full, I/O error): drop the open transaction, so that the
        caller can write its unstored frames again; the trip detector resumes from what is stored."""
        if self.db.in_transaction:
            self.db.execute("ROLLBACK")
        self._pending = 0
        self._pending_since = None
        d = self._trip
        self._trip = _TripDetector(d.moving_mm_s, d.rest_s, d.start_m)
        for tid, node in self.db.execute("SELECT id, node FROM trips WHERE end_time IS NULL"):
            self._trip.open[node] = tid

    def close(self) -> None:
        self.commit()
        self.db.close()

    def __enter__(self) -> "Store":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- reading --------------------------------------------------------------

    def frames(self, node: int | None = None, t0: float | None = None, t1: float | None = None,
               trip: StoredTrip | None = None) -> list[StoredFrame]:
        """Frames in rx_time order, optionally of one node, a time range, or a trip."""
        where: list[str] = []
        args: list[float] = []
        if trip is not None:
            where.append("id >= ?")
            args.append(trip.first_frame_id)
            if trip.last_frame_id is not None:
                where.append("id <= ?")
                args.append(trip.last_frame_id)
            node = trip.node
        if node is not None:
            where.append("node = ?")
            args.append(node)
        if t0 is not None:
            where.append("rx_time >= ?")
            args.append(t0)
        if t1 is not None:
            where.append("rx_time <= ?")
            args.append(t1)
        sql = f"SELECT id, {self._frame_sql} FROM frames"
        if where:
            sql += " WHERE " + " AND ".join(where)
        return self._stored(self.db.execute(sql + " ORDER BY rx_time, id", args).fetchall())

    def rope_series(self, node: int, rope: int, t0: float | None = None, t1: float | None = None,
                    limit: int | None = None, newest_first: bool = False) -> list[tuple[float, int, int]]:
        """(rx_time, mean_dan, raw_kpa) of one rope (from 0) of `node`'s frames within [t0, t1],
        in rx_time order (newest first with `newest_first`), at most `limit` rows."""
        sql = ("SELECT f.rx_time, r.mean_dan, r.raw_kpa FROM frames f JOIN ropes r ON r.frame_id = f.id "
               "AND r.rope = ? WHERE f.node = ?")
        args: list[float] = [rope, node]
        if t0 is not None:
            sql += " AND f.rx_time >= ?"
            args.append(t0)
        if t1 is not None:
            sql += " AND f.rx_time <= ?"
            args.append(t1)
        order = "DESC" if newest_first else "ASC"
        sql += f" ORDER BY f.rx_time {order}, f.id {order}"
        if limit is not None:
            sql += " LIMIT ?"
            args.append(limit)
        return [tuple(r) for r in self.db.execute(sql, args).fetchall()]

    def _stored(self, rows: list) -> list[StoredFrame]:
        """StoredFrames of frames rows (id, *_FRAME_COLS), with their ropes, in the order given."""
        ropes: dict[int, list[Rope]] = {}
        if rows:
            sql = f"SELECT frame_id, rope, {self._rope_sql} FROM ropes WHERE frame_id "
            if len(rows) <= 500:  # a few frames, maybe far apart (one node of several): by id
                ids = [r[0] for r in rows]
                cur = self.db.execute(sql + f"IN ({','.join('?' * len(ids))}) ORDER BY frame_id, rope", ids)
            else:
                cur = self.db.execute(sql + "BETWEEN ? AND ? ORDER BY frame_id, rope",
                                      (min(r[0] for r in rows), max(r[0] for r in rows)))
            for fid, _i, *vals in cur:
                if vals[-1] is None:
                    vals[-1] = POS_ABSENT
                ropes.setdefault(fid, []).append(Rope(*vals))
        out = []
        for fid, rx, rcv, node_, seq, ver, kind, tms, st, fm, dep, spd, bat, oil, auth, mac, smask in rows:
            f = Frame(ver, kind, node_, fm, seq, tms, st, tuple(ropes.get(fid, ())), dep, spd, bat, oil,
                      stroke_mask=smask or 0, authenticated=None if auth is None else bool(auth), mac=bytes(mac))
            out.append(StoredFrame(fid, rx, rcv, f))
        return out

    # -- replay protection across restarts --------------------------------------

    def nodes(self) -> list[int]:
        """Nodes with frames in the log, ascending (one index probe per node, not a scan)."""
        out: list[int] = []
        while True:
            row = self.db.execute("SELECT min(node) FROM frames WHERE node > ?",
                                  (out[-1] if out else -1,)).fetchone()
            if row[0] is None:
                return out
            out.append(row[0])

    def _line_starts(self) -> dict[int, int]:
        """node -> id of the frame row its current sequence starts at: the frame taken
        as its new baseline after an operator-accepted rewind (its last `rebase` event).
        Nodes without one (or whose baseline frame was not stored) count from their first frame."""
        out: dict[int, int] = {}
        for node, seq in self.db.execute("SELECT node, value FROM events WHERE action = 'rebase' "
                                         "AND node IS NOT NULL AND value IS NOT NULL ORDER BY id").fetchall():
            row = self.db.execute("SELECT id FROM frames WHERE node = ? AND seq = ? ORDER BY id DESC LIMIT 1",
                                  (node, int(seq))).fetchone()
            if row is None:
                out.pop(node, None)  # not stored (killed in between): the whole history, refused until re-accepted
            else:
                out[node] = row[0]
        return out

    def last_seqs(self) -> dict[int, int]:
        """node -> newest seq among its authenticated frames (`authenticated` 1: taken by a
        decoder with the node's key) since its current baseline: where a host that
        restarts resumes its replay protection. Frames logged without keys
        (`authenticated` NULL) count for nothing: anyone could have sent them."""
        starts = self._line_starts()
        out: dict[int, int] = {}
        for node in self.nodes():
            row = self.db.execute("SELECT seq FROM frames WHERE node = ? AND authenticated = 1 AND id >= ? "
                                  "ORDER BY seq DESC LIMIT 1", (node, starts.get(node, 0))).fetchone()
            if row is not None:
                out[node] = row[0]
        return out

    def recent_frames(self, node: int, n: int) -> list[Frame]:
        """The last `n` authenticated frames of `node` since its current baseline, oldest
        first: a restarted host still tells their radio retries (duplicates) from replays."""
        start = self._line_starts().get(node, 0)
        rows = self.db.execute(
            f"SELECT id, {self._frame_sql} FROM frames WHERE node = ? AND authenticated = 1 AND id >= ? "
            "ORDER BY rx_time DESC, id DESC LIMIT ?", (node, start, n)).fetchall()
        return [sf.frame for sf in self._stored(rows[::-1])]

    def trips(self, node: int | None = None, *, newest_first: bool = False,
              limit: int | None = None) -> list[StoredTrip]:
        """Trips in start_time order (newest first with `newest_first`), optionally of one node,
        at most `limit`."""
        sql = f"SELECT {_TRIP_SQL} FROM trips"
        args: list[Any] = []
        if node is not None:
            sql += " WHERE node = ?"
            args.append(node)
        order = "DESC" if newest_first else "ASC"
        sql += f" ORDER BY start_time {order}, id {order}"
        if limit is not None:
            sql += " LIMIT ?"
            args.append(limit)
        return [StoredTrip(*r) for r in self.db.execute(sql, args)]

    def trip(self, trip_id: int) -> StoredTrip | None:
        """The trip with this id, None if there is none."""
        row = self.db.execute(f"SELECT {_TRIP_SQL} FROM trips WHERE id = ?", (trip_id,)).fetchone()
        return StoredTrip(*row) if row else None

    def depth_span(self, node: int, first_id: int, last_id: int | None = None) -> int:
        """How far `node`'s depth ranged (highest minus lowest depth_mm) over its frames with
        first_id <= id <= last_id (None: to the newest); 0 without frames."""
        row = self.db.execute("SELECT max(depth_mm) - min(depth_mm) FROM frames WHERE node = ? AND id >= ? "
                              "AND id <= ?", (node, first_id, last_id if last_id is not None else 1 << 62)).fetchone()
        return row[0] or 0

    def frame_buckets(self, node: int, t0: float, t1: float, bucket_s: float) -> list[FrameBucket]:
        """`node`'s frames with t0 <= rx_time <= t1 in buckets of `bucket_s` from t0, in bucket
        order (only buckets with frames): their mean time and depth and their count."""
        rows = self.db.execute(
            "SELECT CAST((rx_time - ?) / ? AS INTEGER) AS b, avg(rx_time), avg(depth_mm), count(*) FROM frames "
            "WHERE node = ? AND rx_time >= ? AND rx_time <= ? GROUP BY b ORDER BY b",
            (t0, bucket_s, node, t0, t1)).fetchall()
        return [FrameBucket(*r) for r in rows]

    def tension_buckets(self, node: int, t0: float, t1: float, bucket_s: float) -> list[TensionBucket]:
        """Each rope's tension over `node`'s frames with t0 <= rx_time <= t1, in the buckets of
        `frame_buckets`, in bucket then rope order; a rope record without a tension is left out."""
        rows = self.db.execute(
            "SELECT CAST((f.rx_time - ?) / ? AS INTEGER) AS b, r.rope, avg(r.mean_dan), min(r.min_dan), "
            "max(r.max_dan) FROM frames f JOIN ropes r ON r.frame_id = f.id "
            "WHERE f.node = ? AND f.rx_time >= ? AND f.rx_time <= ? AND r.mean_dan != ? "
            "GROUP BY b, r.rope ORDER BY b, r.rope",
            (t0, bucket_s, node, t0, t1, L.TENSION_ABSENT)).fetchall()
        return [TensionBucket(*r) for r in rows]

    def events(self, *, since: float | None = None, until: float | None = None, action: str | None = None,
               kind: str | None = None, node: int | None = None, text: str | None = None,
               operator_only: bool = False, by_time: bool = False, newest_first: bool = False,
               limit: int | None = None) -> list[dict[str, Any]]:
        """Rows of the events table as dicts (`id` and the columns of docs/storage.md; an older
        read-only file without `worst` and `operator` has no such keys), in the order they were
        logged (id) or with `by_time` in time_s order (then id), newest first with `newest_first`,
        at most `limit`. Filters: since <= time_s <= until, the action, the kind, the node;
        `text` found in the message, the alarm id or the operator; `operator_only`: what a person
        did (an operator is named, or an acceptance or a baseline; in a file without the
        operator column: the operator actions). `AlarmEvent.from_row` makes an event of a row."""
        where: list[str] = []
        args: list[Any] = []
        operator = "operator" in self._event_cols
        if action:
            where.append("action = ?")
            args.append(action)
        if kind:
            where.append("kind = ?")
            args.append(kind)
        if node is not None:
            where.append("node = ?")
            args.append(node)
        if text:
            where.append("(message LIKE ? ESCAPE '\\' OR alarm LIKE ? ESCAPE '\\'"
                         + (" OR operator LIKE ? ESCAPE '\\')" if operator else ")"))
            pat = "%" + text.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_") + "%"
            args += [pat, pat] + ([pat] if operator else [])
        if since is not None:
            where.append("time_s >= ?")
            args.append(since)
        if until is not None:
            where.append("time_s <= ?")
            args.append(until)
        if operator_only:
            where.append("(operator IS NOT NULL OR action IN ('accept', 'rebase'))" if operator
                         else "action IN ('ack', 'shelve', 'unshelve', 'out_of_service', 'in_service', 'accept')")
        sql = f"SELECT {','.join(self._event_cols)} FROM events"
        if where:
            sql += " WHERE " + " AND ".join(where)
        order = "DESC" if newest_first else "ASC"
        sql += f" ORDER BY time_s {order}, id {order}" if by_time else f" ORDER BY id {order}"
        if limit is not None:
            sql += " LIMIT ?"
            args.append(limit)
        return [dict(zip(self._event_cols, r)) for r in self.db.execute(sql, args)]

    def event_kinds(self) -> list[str]:
        """The distinct kinds in the events table, sorted."""
        return [r[0] for r in self.db.execute("SELECT DISTINCT kind FROM events ORDER BY kind")]

    def link_stats(self) -> list[dict]:
        cur = self.db.execute("SELECT * FROM link_stats ORDER BY id")
        names = [d[0] for d in cur.description]
        return [dict(zip(names, r)) for r in cur]

    def export_csv(self, out_dir: str | Path) -> list[Path]:
        """Write frames.csv, events.csv, link_stats.csv and trips.csv for people and spreadsheets:
        ropes numbered from 1 as on the cage (`r1_mean_dan`, events' `rope`), each time column
        followed by its ISO-8601 UTC form (`rx_time_utc`), an absent oil temperature empty; the
        stroke mask and each rope's piston position (`r1_pos_01mm`), empty where the frame has
        none, then `node_time_ms`: `time_ms` unwrapped per node in arrival order
        (`ropemon.station.nodetime`), a time axis that keeps counting where the node's u32 wraps."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        self.commit()
        n_ropes = self.db.execute("SELECT coalesce(max(rope) + 1, 0) FROM ropes").fetchone()[0]
        rope_fields = ("mean_dan", "min_dan", "max_dan", "raw_kpa")
        # the columns of schema 1 first, in their order; what later versions added last
        cols_v1 = _FRAME_COLS[:-1]
        oil = cols_v1.index("oil_temp_cc") + 1
        paths = []
        p = out / "frames.csv"
        with p.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(_with_utc(["id", *cols_v1], "rx_time")
                       + [f"r{i + 1}_{f}" for i in range(n_ropes) for f in rope_fields]
                       + ["stroke_mask"] + [f"r{i + 1}_pos_01mm" for i in range(n_ropes)]
                       + ["node_time_ms"])
            clock = NodeClock()
            node_i, seq_i, tms_i = (1 + cols_v1.index(c) for c in ("node", "seq", "time_ms"))
            cur = self.db.execute(f"SELECT id, {self._frame_sql} FROM frames ORDER BY id")
            rope_cur = self.db.execute(f"SELECT frame_id, rope, {self._rope_sql} FROM ropes ORDER BY frame_id, rope")
            pending = next(rope_cur, None)
            for row in cur:
                fid = row[0]
                cells = [""] * (4 * n_ropes)
                pos = [""] * n_ropes
                while pending is not None and pending[0] <= fid:
                    if pending[0] == fid:
                        cells[4 * pending[1]: 4 * pending[1] + 4] = pending[2:6]
                        pos[pending[1]] = "" if pending[6] is None else pending[6]
                    pending = next(rope_cur, None)
                row = list(row)
                node_ms = clock.ms_of(row[node_i], row[seq_i], row[tms_i])
                smask = row.pop()
                row[-1] = row[-1].hex()  # mac
                if row[oil] == OIL_TEMP_ABSENT:
                    row[oil] = ""
                w.writerow(_with_utc(row, 1) + cells + ["" if smask is None else smask] + pos
                           + [node_ms])
        paths.append(p)
        for table, times in (("events", ("time_s",)), ("link_stats", ("time_s",)),
                             ("trips", ("start_time", "end_time"))):
            p = out / f"{table}.csv"
            cur = self.db.execute(f"SELECT * FROM {table} ORDER BY id")
            names = [d[0] for d in cur.description]
            at = [names.index(t) for t in times]
            rope = names.index("rope") if table == "events" else None
            with p.open("w", newline="") as fh:
                w = csv.writer(fh)
                w.writerow(_with_utc(names, *times))
                for r in cur:
                    r = list(r)
                    if rope is not None and r[rope] is not None:
                        r[rope] += 1
                    w.writerow(_with_utc(r, *at))
            paths.append(p)
        return paths
