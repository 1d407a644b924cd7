"""`ropemon fleet`: a fleet historian's consumer of the stations' Sparkplug B (an example, and a test).

Subscribes to `spBv1.0/<group>/#` (all groups by default) with a persistent session (QoS 1,
clean_session false, a fixed client id: what the broker queues while the consumer is away
is delivered when it returns), decodes each payload and writes every rope's tension of
every DDATA, with its piston position of the same DDATA (NULL when it carried none), to a
historian table:

    tension(group_id, edge_node, device, node, rope, ts_ms, tension_kn, frame_seq, historical, arrival,
            position_mm)

SQLite (`--db`, default fleet.db), or PostgreSQL/TimescaleDB with `--dsn` (psycopg, not
installed by ropemon: `pip install 'psycopg[binary]'`; on TimescaleDB the table becomes a
hypertable on ts). A row is keyed by (group, edge node, device, node, frame_seq, rope): a
DDATA sent twice (at-least-once: the station resends what the broker had not acknowledged)
is stored once. DBIRTH's values repeat the newest DDATA and are not stored; births, deaths
and gaps in seq are counted (`Fleet.stats`).

Metric names come from the DBIRTH: a DDATA names its metrics by alias only. The aliases an
edge node gave are forgotten at its next NBIRTH, and at its NDEATH (the one whose bdSeq is
that of its NBIRTH: a late will of an older connection is not). A DDATA with an alias the
consumer does not know (it was away during the births) is held, and a rebirth is asked for
(NCMD `Node Control/Rebirth`, at most every `REBIRTH_EVERY_S` per edge node); the new DBIRTH
names it and its rows are written then. A held message is written as it came (topic, payload,
time of arrival) to the historian's `held` table in the transaction of its batch, before it is
acknowledged, so a consumer that stops or dies before the DBIRTH loses nothing: at start it
reads the held messages back and asks their edge nodes for a rebirth. The rows a DBIRTH names
are written and their held messages deleted in one transaction. At most `HOLD` messages are
held per hoist and `HOLD_TOTAL` (or `HOLD_BYTES` of payload) in all (a broken edge node must not
fill the memory or the disk): beyond
that the oldest held message is dropped, counted in `stats["dropped"]` and logged (a warning at
the first drop per hoist, then at most every `DROP_LOG_S` with the count).

Threads: paho's network thread only queues each message; a writer thread takes everything
queued, decodes it, writes its rows in one transaction (a group commit: one per message at a
low rate, many messages per commit under load) and only then acknowledges those messages
(PUBACK, in arrival order; paho's manual ack). Decoding in the writer keeps the network thread
idle, so the writer seldom waits for the GIL between SQLite's steps. A message whose rows are not committed is
not acknowledged, so the broker delivers it again (to this session, after a reconnect).

The consumer takes only what it can account for. A message is refused whole (not written,
acknowledged, counted in `stats["refused_messages"]`) when its topic is not
spBv1.0/<group>/<message type>/<edge node>[/<device>] ("topic"), its payload is over MAX_PAYLOAD
bytes ("too large", not decoded), it is not a Sparkplug B payload ("undecodable": random bytes,
most payloads cut short), it has more than MAX_METRICS metrics ("too many metrics"), or it is a
birth, data or DDEATH without its seq ("no seq": a payload cut short at a field's end), or a
DBIRTH that would take the DBIRTHs whose aliases are kept past BIRTH_BYTES ("too many births":
a rebirth replaces its device's, an edge node's NBIRTH or NDEATH frees its devices'). A primary
host's STATE and commands (NCMD, DCMD) are not data and not refused. Within a message, what the
station cannot have sent is refused, not written: a tension or frame_seq metric whose node number
is not 0..MAX_NODE or rope number not 1..MAX_ROPE ("node or rope"), a frame_seq that is not an
integer in 0..2**63-1 (SQLite's INTEGER, PostgreSQL's BIGINT; the tensions of its node go with it:
"frame_seq"), a tension without its node's frame_seq ("no frame_seq"), a tension that is neither
null nor a finite number ("tension"), a timestamp past MAX_TS_MS ("timestamp"), a position neither
null nor finite (stored as NULL: "position"); each is counted in `stats["refused"]`. Every refusal
is also counted by its reason in `stats["refused_by_reason"]` and logged on this module's logger:
a warning at the first of a reason, then at most one line per reason every REFUSE_LOG_S with the
count since (written by the writer within the period even when no more come).

Metric names are parsed once (tension, position, frame_seq: node and rope) and remembered in a
cache of at most NAME_CACHE names; a name past it empties the cache, which starts again
(`stats["name_cache_cleared"]`, logged): the cache only saves parsing, so a new name is never
refused for it and the names in use come back at their next message.

A batch whose transaction fails for a reason of its data (not the database: `_data_error`) is
written again message by message: a message the database still refuses ("historian"), or one
that cannot be read ("unreadable"), is dropped, counted, logged and acknowledged, so that it is
not delivered again forever; the others are committed and acknowledged in order. A database that
cannot be written at all (disk full, locked, gone) keeps the whole batch, unacknowledged, and the
writer tries it again every second.

Where a message came from is the broker's to check (its ACL: docs/integration.md): a Sparkplug B
payload carries no signature, and its seq and bdSeq are no proof either (anyone who reads the
topics can send the next one, and the consumer sees gaps and repeats in normal operation: births
are QoS 0, not kept for it while it is away, and what it did not acknowledge comes again).
"""
from __future__ import annotations

import argparse
import logging
import math
import queue
import re
import signal
import sqlite3
import sys
import threading
import time
from pathlib import Path
from collections import deque
from typing import Any

log = logging.getLogger(__name__)
TENSION = re.compile(r"^node([0-9]+)/rope([0-9]+)/tension$")
POSITION = re.compile(r"^node([0-9]+)/rope([0-9]+)/position$")
SEQ = re.compile(r"^node([0-9]+)/frame_seq$")
MAX_NODE = 255           # a node id is one byte (docs/protocol.md)
MAX_ROPE = 255           # ropes count from 1
MAX_SEQ = 2**63 - 1      # frame_seq is a UInt64; the historian's column a signed 64-bit integer
MAX_TS_MS = 253_402_300_799_999   # 9999-12-31 23:59:59.999 UTC: beyond it PostgreSQL's to_timestamp fails
REFUSE_LOG_S = 60.0      # refused metrics and messages logged at most this often per reason (after the first)
MAX_PAYLOAD = 65_536     # bytes per message at most (a ropemon DBIRTH: 1.8 kB per cage node, 3.4 kB for two)
MAX_METRICS = 1_000      # metrics per message at most (a ropemon DBIRTH: 34 for one cage node, 63 for two)
NAME_CACHE = 10_000      # metric names whose parse is remembered (a ropemon station's for all 256 node ids: 7,429)
KINDS = {"NBIRTH": 4, "NDEATH": 4, "NDATA": 4, "NCMD": 4, "DBIRTH": 5, "DDEATH": 5, "DDATA": 5, "DCMD": 5}
HOLD = 10_000            # DDATA held per hoist while its aliases are unknown (1,000 s at 10 frames/s)
HOLD_TOTAL = 100_000     # DDATA held in all (about 40 MB at 400 bytes each), over every hoist
HOLD_BYTES = 64 << 20    # and their payloads at most this many bytes in all (64 MiB)
BIRTH_BYTES = 16 << 20   # the DBIRTHs whose aliases are kept, bytes in all (16 MiB: 4,900 hoists of two nodes)
DROP_LOG_S = 60.0        # a hoist's dropped held DDATA logged at most this often (after the first)
REBIRTH_EVERY_S = 5.0    # at most one rebirth request per edge node this often

SQLITE_SCHEMA = """
CREATE TABLE IF NOT EXISTS tension (
    group_id TEXT NOT NULL, edge_node TEXT NOT NULL, device TEXT NOT NULL, node INTEGER NOT NULL,
    rope INTEGER NOT NULL, ts_ms INTEGER NOT NULL, tension_kn REAL, frame_seq INTEGER NOT NULL,
    historical INTEGER NOT NULL, arrival INTEGER NOT NULL, position_mm REAL,
    PRIMARY KEY (group_id, edge_node, device, node, frame_seq, rope));
CREATE TABLE IF NOT EXISTS held (
    id INTEGER PRIMARY KEY, group_id TEXT NOT NULL, edge_node TEXT NOT NULL, device TEXT NOT NULL,
    topic TEXT NOT NULL, payload BLOB NOT NULL, arrival_ms INTEGER NOT NULL);
"""
PG_SCHEMA = """
CREATE TABLE IF NOT EXISTS tension (
    group_id TEXT NOT NULL, edge_node TEXT NOT NULL, device TEXT NOT NULL, node INTEGER NOT NULL,
    rope INTEGER NOT NULL, ts TIMESTAMPTZ NOT NULL, tension_kn DOUBLE PRECISION, frame_seq BIGINT NOT NULL,
    historical BOOLEAN NOT NULL, arrival BIGINT NOT NULL, position_mm DOUBLE PRECISION,
    PRIMARY KEY (group_id, edge_node, device, node, frame_seq, rope, ts));
ALTER TABLE tension ADD COLUMN IF NOT EXISTS position_mm DOUBLE PRECISION;
CREATE TABLE IF NOT EXISTS held (
    id BIGINT PRIMARY KEY, group_id TEXT NOT NULL, edge_node TEXT NOT NULL, device TEXT NOT NULL,
    topic TEXT NOT NULL, payload BYTEA NOT NULL, arrival_ms BIGINT NOT NULL);
"""


_COLUMNS = "group_id, edge_node, device, node, rope, {ts}, tension_kn, frame_seq, historical, arrival, position_mm"
SQLITE_COLUMNS, PG_COLUMNS = _COLUMNS.format(ts="ts_ms"), _COLUMNS.format(ts="ts")


class Historian:
    """Where the tensions go: SQLite by default, PostgreSQL/TimescaleDB with a DSN."""

    def __init__(self, db: str | Path | None = None, dsn: str | None = None) -> None:
        self.pg = dsn is not None
        self.arrival = 0
        if self.pg:
            import psycopg  # optional: pip install 'psycopg[binary]'
            self.conn: Any = psycopg.connect(dsn, autocommit=False)
            with self.conn.cursor() as cur:
                cur.execute(PG_SCHEMA)
                cur.execute("SELECT 1 FROM pg_extension WHERE extname = 'timescaledb'")
                if cur.fetchone():
                    cur.execute("SELECT create_hypertable('tension', 'ts', if_not_exists => TRUE)")
                cur.execute("SELECT COALESCE(MAX(arrival), 0) FROM tension")
                self.arrival = cur.fetchone()[0]
            self.conn.commit()
        else:
            self.conn = sqlite3.connect(str(db or "fleet.db"), check_same_thread=False)
            self.conn.execute("PRAGMA journal_mode=WAL")   # readers go on while a batch commits
            self.conn.executescript(SQLITE_SCHEMA)
            if "position_mm" not in {r[1] for r in self.conn.execute("PRAGMA table_info(tension)")}:
                with self.conn:     # a historian made before the pistons' positions: the column added
                    self.conn.execute("ALTER TABLE tension ADD COLUMN position_mm REAL")
            self.arrival = self.conn.execute("SELECT COALESCE(MAX(arrival), 0) FROM tension").fetchone()[0]

    def write(self, rows: list[tuple], hold: list[tuple] = (), unhold: list[int] = ()) -> None:
        """One transaction. rows: (group, edge, device, node, rope, ts_ms, tension_kn, frame_seq,
        historical[, position_mm]); hold: held messages to keep (id, group, edge, device, topic,
        payload, arrival_ms); unhold: the ids of held messages to delete (named and written, or dropped)."""
        out = []
        for r in rows:
            self.arrival += 1
            out.append((*r[:9], self.arrival, r[9] if len(r) > 9 else None))
        gone = [(i,) for i in unhold]
        if self.pg:
            try:
                with self.conn.cursor() as cur:
                    if out:
                        cur.executemany(
                            f"INSERT INTO tension ({PG_COLUMNS}) VALUES (%s, %s, %s, %s, %s, to_timestamp(%s / 1000.0), "
                            "%s, %s, %s, %s, %s) ON CONFLICT DO NOTHING", out)
                    if hold:
                        cur.executemany("INSERT INTO held VALUES (%s, %s, %s, %s, %s, %s, %s) ON CONFLICT DO NOTHING",
                                        list(hold))
                    if gone:
                        cur.executemany("DELETE FROM held WHERE id = %s", gone)
                self.conn.commit()
            except Exception:
                self.conn.rollback()
                self.arrival -= len(out)
                raise
        else:
            try:
                with self.conn:
                    if out:
                        self.conn.executemany(f"INSERT OR IGNORE INTO tension ({SQLITE_COLUMNS}) "
                                              "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", out)
                    if hold:
                        self.conn.executemany("INSERT OR IGNORE INTO held VALUES (?, ?, ?, ?, ?, ?, ?)", list(hold))
                    if gone:
                        self.conn.executemany("DELETE FROM held WHERE id = ?", gone)
            except Exception:
                self.arrival -= len(out)
                raise

    def held(self) -> list[tuple]:
        """The held messages, oldest first: (id, group, edge, device, topic, payload, arrival_ms)."""
        if self.pg:
            with self.conn.cursor() as cur:
                cur.execute("SELECT id, group_id, edge_node, device, topic, payload, arrival_ms FROM held ORDER BY id")
                got = [(*r[:5], bytes(r[5]), r[6]) for r in cur.fetchall()]
            self.conn.commit()
            return got
        return self.conn.execute(
            "SELECT id, group_id, edge_node, device, topic, payload, arrival_ms FROM held ORDER BY id").fetchall()

    def close(self) -> None:
        self.conn.close()


MAX_BATCH_ROWS = 20_000    # rows per transaction at most (the writer takes what is queued, up to this)


class Fleet:
    """The consumer: paho-mqtt's network thread decodes, a writer thread commits then acknowledges
    (module docstring)."""

    def __init__(self, historian: Historian, host: str = "127.0.0.1", port: int = 1883, group: str = "+",
                 client_id: str = "ropemon-fleet", username: str | None = None, password: str | None = None,
                 tls: bool = False, tls_ca: str | None = None) -> None:
        import paho.mqtt.client as paho
        self.historian = historian
        self.topic = f"spBv1.0/{group}/#"
        self.stats = {"births": 0, "deaths": 0, "ddata": 0, "rows": 0, "seq_gaps": 0, "historical": 0,
                      "commits": 0, "held": 0, "dropped": 0, "rebirths_asked": 0, "refused": 0,
                      "refused_messages": 0, "refused_by_reason": {}, "name_cache_cleared": 0}
        self.seq: dict[tuple[str, str], int] = {}     # (group, edge) -> last seq
        self.bdseq: dict[tuple[str, str], int] = {}   # (group, edge) -> bdSeq of its NBIRTH
        self.aliases: dict[tuple[str, str, str], dict[int, str]] = {}   # (group, edge, device) -> alias -> name
        # DDATA waiting for their DBIRTH: (group, edge, device) -> deque of (held id, topic, payload, arrival_ms)
        self.held: dict[tuple[str, str, str], deque[tuple[int, str, bytes, int]]] = {}
        self.held_count = 0
        self.held_bytes = 0                    # their payloads' bytes
        self._birth_bytes: dict[tuple[str, str, str], int] = {}   # dkey -> its DBIRTH's bytes (aliases kept)
        self.birth_bytes = 0                   # ... in all
        self._held_id = 0
        self._hold_new: list[tuple] = []       # held messages for the next transaction's `held` table
        self._hold_gone: list[int] = []        # held ids to delete in it (named and written, or dropped)
        self._dropped_said: dict[tuple[str, str, str], tuple[float, int]] = {}   # dkey -> (logged at, dropped then)
        self._asked: dict[tuple[str, str], float] = {}                  # (group, edge) -> rebirth asked at
        self._cache_said = -1e18                    # the name cache's emptying logged at (monotonic)
        self._refused_said: dict[str, list] = {}    # reason -> [logged at, refused since, "refused" | "refused_messages"]
        self.connected = threading.Event()       # subscribed: the broker acknowledged the subscription
        self.lock = threading.Lock()
        self.error: str | None = None                  # the historian cannot be written (the writer retries)
        self._names: dict[str, tuple[str, int, int] | None] = {}   # metric name -> ("t"|"s", node, rope)
        self._queue: "queue.SimpleQueue[tuple[int, int, int, str, bytes]]" = queue.SimpleQueue()
        self._session = 0             # +1 at each connect and disconnect: an old connection's mids are not acked
        self._ack_lock = threading.Lock()
        self._stop = threading.Event()
        self._writer = threading.Thread(target=self._write_loop, name="fleet-writer", daemon=True)
        c = self.client = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False,
                                      protocol=paho.MQTTv311, manual_ack=True)
        if username:
            c.username_pw_set(username, password)
        if tls:
            c.tls_set(ca_certs=tls_ca)
        c.reconnect_delay_set(1, 2)
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        c.on_message = self._on_message
        c.on_subscribe = self._on_subscribe
        self.host, self.port = host, port
        for hid, group, edge, device, topic, data, arrival_ms in historian.held():   # a previous run's
            self.held.setdefault((group, edge, device), deque()).append((hid, topic, bytes(data), arrival_ms))
            self.held_count += 1
            self.held_bytes += len(data)
            self._held_id = max(self._held_id, hid)
        self.stats["held_loaded"] = self.held_count

    def start(self) -> None:
        self._writer.start()
        self.client.connect_async(self.host, self.port, keepalive=10)
        self.client.loop_start()

    def stop(self) -> None:
        """Disconnect, then commit what was received (not acknowledged: the broker sends it again)."""
        self.client.disconnect()
        self.client.loop_stop()
        self._stop.set()
        self._writer.join(30.0)

    def _on_connect(self, client, userdata, flags, reason, props) -> None:
        if not reason.is_failure:
            with self._ack_lock:
                self._session += 1
            client.subscribe(self.topic, qos=1)
            with self.lock:                  # held messages (of a previous run too): ask their births
                for group, edge in {k[:2] for k, q in self.held.items() if q}:
                    self._ask_rebirth(group, edge)

    def _on_subscribe(self, client, userdata, mid, reasons, props) -> None:
        """SUBACK: from now on the broker sends this consumer what is published (births are QoS 0,
        not kept for a consumer not yet subscribed), so `connected` is set only now."""
        if reasons and not any(r.is_failure for r in reasons):
            self.connected.set()
        else:
            log.warning("fleet: the broker refused the subscription to %s: %s", self.topic, reasons)

    def _on_disconnect(self, *args: Any) -> None:
        with self._ack_lock:
            self._session += 1
        self.connected.clear()

    def _on_message(self, client, userdata, msg) -> None:
        self._queue.put((self._session, msg.mid, msg.qos, msg.topic, msg.payload))

    def _name(self, name: str) -> tuple[str, int, int] | None:
        """("t", node, rope) of a tension, ("s", node, 0) of a frame_seq, ("bad", 0, 0) of either
        with a node or rope number the station cannot have sent, None of any other metric."""
        t = TENSION.match(name) or POSITION.match(name)
        if t is not None:
            node, rope = t.group(1), t.group(2)
            if len(node) > 3 or len(rope) > 3 or not (0 <= int(node) <= MAX_NODE and 1 <= int(rope) <= MAX_ROPE):
                return ("bad", 0, 0)
            return ("t" if name.endswith("/tension") else "p", int(node), int(rope))
        s = SEQ.match(name)
        if s is None:
            return None
        node = s.group(1)
        return ("s", int(node), 0) if len(node) <= 3 and int(node) <= MAX_NODE else ("bad", 0, 0)

    def _refuse(self, topic: str, reason: str, detail: str, n: int = 1, what: str = "refused") -> None:
        """Count n refused metrics (or messages: what="refused_messages") under `reason` (a short
        fixed text: the key of stats["refused_by_reason"]) and log it: a warning at the first of the
        reason, then at most one line per reason every REFUSE_LOG_S with the count since (here or
        in `_say_refused`) (self.lock held)."""
        self.stats[what] += n
        by = self.stats["refused_by_reason"]
        by[reason] = by.get(reason, 0) + n
        said = self._refused_said.setdefault(reason, [None, 0, what])
        said[1] += n
        now = time.monotonic()
        if said[0] is None or now - said[0] >= REFUSE_LOG_S:
            log.warning("fleet: %.200s: %s not written (%s): %s; %d since the last line for this reason, %d in all",
                        topic, "metric(s)" if what == "refused" else "message", reason, detail, said[1], by[reason])
            said[0], said[1] = now, 0

    def _say_refused(self, force: bool = False) -> None:
        """The counts of refusals not yet logged, one line per reason whose last line is REFUSE_LOG_S
        old (or at once: `force`, at the stop) (self.lock held)."""
        now = time.monotonic()
        for reason, said in self._refused_said.items():
            if said[1] and (force or now - said[0] >= REFUSE_LOG_S):
                log.warning("fleet: %s not written (%s): %d since the last line for this reason, %.0f s ago; "
                            "%d in all", "metric(s)" if said[2] == "refused" else "messages", reason, said[1],
                            now - said[0], self.stats["refused_by_reason"][reason])
                said[0], said[1] = now, 0

    def rows_of(self, topic: str, payload: bytes) -> list[tuple]:
        """One message's historian rows (none for births, deaths and commands); a message that is
        not Sparkplug B or past the limits refused whole (module docstring)."""
        from ropemon.station.mqtt import sparkplug as sp
        parts = topic.split("/")
        if len(parts) == 3 and parts[0] == sp.NAMESPACE and parts[1] == "STATE":
            return []                           # a primary host's STATE (JSON): not for the historian
        kind = parts[2] if len(parts) > 2 else ""
        if parts[0] != sp.NAMESPACE or KINDS.get(kind) != len(parts) or not all(parts[1:]):
            return self._refuse_message(topic, "topic", "not spBv1.0/<group>/<message type>/<edge node>[/<device>]")
        if kind in ("NCMD", "DCMD"):
            return []                           # commands to an edge node (this consumer's rebirths too)
        if len(payload) > MAX_PAYLOAD:
            return self._refuse_message(topic, "too large", f"{len(payload)} bytes, more than {MAX_PAYLOAD}")
        try:
            p = sp.decode(payload)
        except Exception as e:  # noqa: BLE001 - not Sparkplug B, or cut short
            return self._refuse_message(topic, "undecodable", f"not a Sparkplug B payload ({type(e).__name__})")
        if len(p.metrics) > MAX_METRICS:
            return self._refuse_message(topic, "too many metrics", f"{len(p.metrics)}, more than {MAX_METRICS}")
        if kind != "NDEATH" and not p.HasField("seq"):
            return self._refuse_message(topic, "no seq", "a birth, data or death without its seq (cut short?)")
        group, edge = parts[1], parts[3]
        device = parts[4] if len(parts) > 4 else None
        with self.lock:
            key = (group, edge)
            if kind in ("NBIRTH", "NDEATH"):
                self.stats["births" if kind == "NBIRTH" else "deaths"] += 1
                bd = next((sp.metric_value(m) for m in p.metrics if m.name == "bdSeq"), None)
                if kind == "NBIRTH" or bd is None or self.bdseq.get(key, bd) == bd:
                    for k in [k for k in self.aliases if k[:2] == key]:    # a session ends: its aliases
                        del self.aliases[k]
                        self.birth_bytes -= self._birth_bytes.pop(k, 0)
                if bd is not None and (kind == "NBIRTH" or key not in self.bdseq):
                    self.bdseq[key] = bd
                if kind == "NBIRTH":
                    self.seq[key] = p.seq
                return []
            if p.HasField("seq") and key in self.seq:
                if p.seq != (self.seq[key] + 1) % 256:
                    self.stats["seq_gaps"] += 1
            if p.HasField("seq"):
                self.seq[key] = p.seq
            if device is None:
                return []
            dkey = (group, edge, device)
            if kind == "DBIRTH":
                was = self._birth_bytes.get(dkey, 0)
                if self.birth_bytes - was + len(payload) > BIRTH_BYTES:
                    self._refuse(topic, "too many births", f"the DBIRTHs whose aliases are kept would take more "
                                 f"than {BIRTH_BYTES} bytes", what="refused_messages")
                    return []
                self.birth_bytes += len(payload) - was
                self._birth_bytes[dkey] = len(payload)
                self.aliases[dkey] = aliases = {m.alias: m.name for m in p.metrics if m.HasField("alias")}
                rows = []
                held = self.held.pop(dkey, None)
                if held:
                    still: deque[tuple[int, str, bytes, int]] = deque()
                    for item in held:
                        q = sp.decode(item[2])
                        if any(not m.name and m.alias not in aliases for m in q.metrics):
                            still.append(item)       # this DBIRTH does not name it either: held on
                            continue
                        rows += self._ddata_rows(dkey, q, item[1])
                        self._hold_gone.append(item[0])
                        self.held_count -= 1
                        self.held_bytes -= len(item[2])
                    if still:
                        self.held[dkey] = still
                return rows
            if kind != "DDATA":
                return []
            aliases = self.aliases.get(dkey, {})
            if any(not m.name and m.alias not in aliases for m in p.metrics):
                self._hold(dkey, topic, payload)
                return []
            return self._ddata_rows(dkey, p, topic)

    def _refuse_message(self, topic: str, reason: str, detail: str) -> list[tuple]:
        """A message refused whole: counted, logged, no rows (it is acknowledged with its batch)."""
        with self.lock:
            self._refuse(topic, reason, detail, what="refused_messages")
        return []

    def _ddata_rows(self, dkey: tuple[str, str, str], p: Any, topic: str) -> list[tuple]:
        """A DDATA's tension rows, its metrics named by the DBIRTH's aliases; what the station cannot
        have sent refused (module docstring) (self.lock held)."""
        from ropemon.station.mqtt import sparkplug as sp
        group, edge, device = dkey
        aliases = self.aliases.get(dkey, {})
        self.stats["ddata"] += 1
        seqs: dict[int, Any] = {}
        tensions = []
        positions: dict[tuple[int, int], float | None] = {}
        names = self._names
        for m in p.metrics:
            name = m.name or aliases[m.alias]
            what = names.get(name, ...)
            if what is ...:
                what = self._name(name)
                if len(names) >= NAME_CACHE:      # bounded: emptied, the names in use come back at once
                    names.clear()
                    self._name_cache_cleared()
                names[name] = what
            if what is None:
                continue
            if what[0] == "bad":
                self._refuse(topic, "node or rope", f"{name!r:.60}: node not 0..{MAX_NODE} or rope not 1..{MAX_ROPE}")
            elif what[0] == "s":
                v = sp.metric_value(m)
                if v is not None and (type(v) is not int or not 0 <= v <= MAX_SEQ):
                    self._refuse(topic, "frame_seq",
                                 f"{name} = {v!r:.40}: not an integer 0..2**63-1 (nor its node's tensions)")
                    v = ...
                seqs[what[1]] = v
            elif what[0] == "p":
                v = sp.metric_value(m)
                if type(v) is int:
                    v = float(v)
                if v is not None and (type(v) is not float or not math.isfinite(v)):
                    self._refuse(topic, "position",
                                 f"{name} = {v!r:.40}: neither null nor a finite number (stored as NULL)")
                    v = None
                positions[(what[1], what[2])] = v
            else:
                tensions.append((what[1], what[2], m))
        rows = []
        for node, rope, m in tensions:
            seq = seqs.get(node, None)
            if seq is None:
                self._refuse(topic, "no frame_seq", f"node{node}/rope{rope}/tension: its node's frame_seq "
                             "is not in the message (or null)")
                continue
            if seq is ...:
                self._refuse(topic, "frame_seq", f"node{node}/rope{rope}/tension: its node's frame_seq was refused")
                continue
            v = sp.metric_value(m)
            if type(v) is int:              # an integer metric type: REAL in the historian
                v = float(v)
            if v is not None and (type(v) is not float or not math.isfinite(v)):
                self._refuse(topic, "tension",
                             f"node{node}/rope{rope}/tension = {v!r:.40}: neither null nor a finite number")
                continue
            if not 0 <= m.timestamp <= MAX_TS_MS:
                self._refuse(topic, "timestamp",
                             f"node{node}/rope{rope}/tension: timestamp {m.timestamp} past year 9999")
                continue
            rows.append((group, edge, device, node, rope, m.timestamp, v, seq, bool(m.is_historical),
                         positions.get((node, rope))))
            self.stats["historical"] += bool(m.is_historical)
        return rows

    def _name_cache_cleared(self) -> None:
        """The name cache was full and has been emptied: counted, logged at most every REFUSE_LOG_S
        (a station sends far fewer names: someone sends many new ones) (self.lock held)."""
        self.stats["name_cache_cleared"] += 1
        now = time.monotonic()
        if now - self._cache_said >= REFUSE_LOG_S:
            self._cache_said = now
            log.warning("fleet: the metric name cache was full (%d names; a ropemon station sends at most 7,429): "
                        "emptied, %d times in all (nothing refused for it)", NAME_CACHE,
                        self.stats["name_cache_cleared"])

    def _hold(self, dkey: tuple[str, str, str], topic: str, payload: bytes) -> None:
        """A DDATA with an alias no DBIRTH named: held (in the `held` table with the batch), the
        oldest dropped past HOLD for the hoist or HOLD_TOTAL in all; a rebirth asked for (self.lock held)."""
        self._held_id += 1
        item = (self._held_id, topic, bytes(payload), int(time.time() * 1000))
        held = self.held.setdefault(dkey, deque())
        held.append(item)
        self.held_count += 1
        self.held_bytes += len(item[2])
        self._hold_new.append((item[0], *dkey, item[1], item[2], item[3]))
        self.stats["held"] += 1
        while len(held) > HOLD:
            self._drop(dkey)
        while self.held_count > HOLD_TOTAL or self.held_bytes > HOLD_BYTES:
            self._drop(min((k for k, q in self.held.items() if q), key=lambda k: self.held[k][0][0]))
        self._ask_rebirth(dkey[0], dkey[1])

    def _drop(self, dkey: tuple[str, str, str]) -> None:
        """Drop the hoist's oldest held DDATA: lost, counted and logged (self.lock held)."""
        held = self.held[dkey]
        hid, _, data, _ = held.popleft()
        if not held:
            del self.held[dkey]
        self._hold_gone.append(hid)
        self.held_count -= 1
        self.held_bytes -= len(data)
        self.stats["dropped"] += 1
        now = time.monotonic()
        said_at, n = self._dropped_said.get(dkey, (None, 0))
        n += 1
        if said_at is None or now - said_at >= DROP_LOG_S:
            log.warning("fleet: %s/%s/%s: %d DDATA dropped unwritten (oldest first): their aliases are unknown and "
                        "more than %d are held for the hoist or %d (%d MiB) in all (no DBIRTH came after the rebirth "
                        "asked)", *dkey, n, HOLD, HOLD_TOTAL, HOLD_BYTES >> 20)
            said_at, n = now, 0
        self._dropped_said[dkey] = (said_at, n)

    def _ask_rebirth(self, group: str, edge: str) -> None:
        """NCMD Node Control/Rebirth to the edge node, at most every REBIRTH_EVERY_S (self.lock held)."""
        from ropemon.station.mqtt import sparkplug as sp
        now = time.monotonic()
        if now - self._asked.get((group, edge), -REBIRTH_EVERY_S) >= REBIRTH_EVERY_S:
            self._asked[(group, edge)] = now
            cmd = sp.payload(None)
            sp.add_metric(cmd, "Node Control/Rebirth", sp.BOOLEAN, True, cmd.timestamp)
            self.client.publish(sp.topic(group, "NCMD", edge), cmd.SerializeToString(), qos=0)
            self.stats["rebirths_asked"] += 1

    def _write_loop(self) -> None:
        """Take what is queued, commit it in one transaction, then acknowledge it; a batch its data
        made fail is written message by message, a message still refused set aside (module docstring)."""
        batch: list[tuple] = []        # per message: ((session, mid, qos), topic, rows, hold, unhold); kept for a retry
        while True:
            if not batch:
                try:
                    item = self._queue.get(timeout=0.2)
                except queue.Empty:
                    with self.lock:
                        self._say_refused(force=self._stop.is_set())
                    if self._stop.is_set():
                        return
                    continue
                n = 0
                try:
                    while True:
                        session, mid, qos, topic, payload = item
                        try:
                            rows = self.rows_of(topic, payload)
                        except Exception as e:  # noqa: BLE001 - one unreadable message must not stop the writer
                            rows = []
                            with self.lock:
                                self._refuse(topic, "unreadable", f"cannot be read: {type(e).__name__}: {e}",
                                             what="refused_messages")
                        batch.append(((session, mid, qos), topic, rows, self._hold_new, self._hold_gone))
                        n += len(rows) + len(self._hold_new)
                        self._hold_new, self._hold_gone = [], []
                        if n >= MAX_BATCH_ROWS:
                            break
                        item = self._queue.get_nowait()
                except queue.Empty:
                    pass
            try:
                self._commit(batch)
            except Exception as e:  # noqa: BLE001 - not acknowledged: tried again, or message by message
                if not _data_error(e):
                    self.error = f"cannot write the historian: {type(e).__name__}: {e}"
                    if self._stop.wait(1.0):
                        return
                    continue
                failed = None
                while batch:                        # its data: each message alone, in order
                    try:
                        self._commit(batch[:1])
                    except Exception as e1:  # noqa: BLE001
                        if not _data_error(e1):     # the database itself now: the rest kept, tried again
                            failed = f"cannot write the historian: {type(e1).__name__}: {e1}"
                            break
                        with self.lock:
                            self._refuse(batch[0][1], "historian", f"the historian refused it: {type(e1).__name__}: "
                                         f"{e1}", what="refused_messages")
                    self._ack(batch[:1])
                    del batch[0]
                if batch:
                    self.error = failed
                    if self._stop.wait(1.0):
                        return
                continue
            self._ack(batch)
            batch = []
            with self.lock:
                self._say_refused()

    def _commit(self, batch: list[tuple]) -> None:
        """The messages' rows and held messages in one transaction (none when there is nothing to write)."""
        rows = [r for m in batch for r in m[2]]
        hold = [h for m in batch for h in m[3]]
        unhold = [u for m in batch for u in m[4]]
        if rows or hold or unhold:
            self.historian.write(rows, hold, unhold)
            self.error = None
            with self.lock:
                self.stats["rows"] += len(rows)
                self.stats["commits"] += 1

    def _ack(self, batch: list[tuple]) -> None:
        """PUBACK the messages, in order (those of the current connection only)."""
        with self._ack_lock:
            for (session, mid, qos), *_ in batch:
                if qos and session == self._session:
                    self.client.ack(mid, qos)


def _data_error(e: BaseException) -> bool:
    """Whether a failed write is its data's fault (a value the database cannot take: the message
    is set aside) rather than the database's (it cannot be written at all: disk full, locked,
    closed, gone; everything is kept and tried again)."""
    if isinstance(e, (OverflowError, ValueError, TypeError, sqlite3.IntegrityError, sqlite3.DataError,
                      sqlite3.InterfaceError)):
        return True
    names = {c.__name__ for c in type(e).__mro__}          # psycopg's, without importing it
    return type(e).__module__.startswith("psycopg") and bool(names & {"DataError", "IntegrityError"})


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", default="127.0.0.1", help="the MQTT broker (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=1883)
    p.add_argument("--group", default="+", help="the Sparkplug group id (default: every group)")
    p.add_argument("--client-id", default="ropemon-fleet", help="fixed: the broker keeps this consumer's session")
    p.add_argument("--db", default="fleet.db", help="SQLite historian (default fleet.db)")
    p.add_argument("--dsn", help="PostgreSQL/TimescaleDB instead of SQLite (needs psycopg)")
    p.add_argument("--username")
    p.add_argument("--password-file", help="a file whose only line is the password")
    p.add_argument("--tls", action="store_true")
    p.add_argument("--tls-ca", help="CA certificate file (default: the system's)")
    p.add_argument("--seconds", type=float, default=None, help="stop after this long (default: until Ctrl-C)")


def run(args: argparse.Namespace) -> int:
    password = Path(args.password_file).read_text().strip() if args.password_file else None
    try:
        historian = Historian(args.db, args.dsn)
    except ImportError:
        print("ropemon fleet: --dsn needs psycopg: pip install 'psycopg[binary]'", file=sys.stderr)
        return 2
    fleet = Fleet(historian, args.host, args.port, args.group, args.client_id, args.username, password,
                  args.tls, args.tls_ca)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    fleet.start()
    print(f"ropemon fleet: {fleet.topic} on {args.host}:{args.port} -> {args.dsn and 'PostgreSQL' or args.db}",
          file=sys.stderr)
    end = None if args.seconds is None else time.monotonic() + args.seconds
    while not stop.is_set() and (end is None or time.monotonic() < end):
        stop.wait(1.0)
    fleet.stop()
    historian.close()
    print(f"ropemon fleet: {fleet.stats}", file=sys.stderr)
    return 0
