"""The MQTT face's store-and-forward buffer: every DDATA's values, on disk, until the broker
has acknowledged them (SQLite: `<data_dir>/mqtt-outbox.db`; in memory without a data_dir).

Used by the publisher thread only. Rows are kept in the order they were queued (their id,
given here: consecutive over one `add`), a hoist's death or birth ({"$device": "death"})
among its data; past `max_rows` the oldest are dropped and counted. `add` commits (the
durability point: a row added is sent, again after a crash if it was not acknowledged);
`delete` takes the acknowledged rows in one transaction. `meta` keeps the edge node's bdSeq
across restarts.
"""
from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any, Iterable

SCHEMA = """
CREATE TABLE IF NOT EXISTS outbox (id INTEGER PRIMARY KEY AUTOINCREMENT, device TEXT NOT NULL,
                                   ts_ms INTEGER NOT NULL, body TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value INTEGER NOT NULL);
"""


class Outbox:
    def __init__(self, path: Path | None, max_rows: int) -> None:
        self.path = path
        self.max_rows = max_rows
        self.db = sqlite3.connect(str(path) if path is not None else ":memory:", isolation_level=None)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=NORMAL")
        self.db.executescript(SCHEMA)
        self.dropped = 0
        self.rows = self.db.execute("SELECT COUNT(*) FROM outbox").fetchone()[0]
        self.next_id = max(self.last_id(), self.db.execute("SELECT COALESCE(MAX(id), 0) FROM outbox").fetchone()[0]) + 1

    def add(self, records: Iterable[tuple[str, int, dict[str, Any]]]) -> int:
        """Queue the records in one transaction; returns the id of the first (the others follow it)."""
        first = self.next_id
        rows = [(first + k, dev, ts, json.dumps(values, separators=(",", ":")))
                for k, (dev, ts, values) in enumerate(records)]
        if not rows:
            return first
        with self.db:   # one transaction
            self.db.execute("BEGIN")
            self.db.executemany("INSERT INTO outbox (id, device, ts_ms, body) VALUES (?, ?, ?, ?)", rows)
            self.rows += len(rows)
            if self.rows > self.max_rows:
                over = self.rows - self.max_rows
                self.db.execute("DELETE FROM outbox WHERE id IN (SELECT id FROM outbox ORDER BY id LIMIT ?)", (over,))
                self.dropped += over
                self.rows -= over
        self.next_id = first + len(rows)
        return first

    def after(self, row_id: int, limit: int) -> list[tuple[int, str, int, dict[str, Any]]]:
        cur = self.db.execute("SELECT id, device, ts_ms, body FROM outbox WHERE id > ? ORDER BY id LIMIT ?",
                              (row_id, limit))
        return [(i, d, t, json.loads(b)) for i, d, t, b in cur]

    def delete(self, ids: list[int]) -> None:
        if ids:
            with self.db:
                self.db.execute("BEGIN")
                cur = self.db.executemany("DELETE FROM outbox WHERE id = ?", [(i,) for i in ids])
            self.rows -= cur.rowcount

    def last_id(self) -> int:
        """The id of the newest row ever queued (0: none)."""
        row = self.db.execute("SELECT seq FROM sqlite_sequence WHERE name = 'outbox'").fetchone()
        return row[0] if row else 0

    def devices_between(self, after: int, before: int) -> set[str]:
        """The devices with data rows (not deaths or births) after `after` and older than `before`."""
        cur = self.db.execute("SELECT DISTINCT device FROM outbox WHERE id > ? AND id < ? "
                              "AND body NOT LIKE '{\"$device\"%'", (after, before))
        return {d for (d,) in cur}

    def first_states(self, row_id: int) -> dict[str, str]:
        """Each device's first death or birth row from `row_id` on: device -> "death" | "birth"."""
        cur = self.db.execute("SELECT device, body FROM outbox WHERE id IN (SELECT MIN(id) FROM outbox "
                              "WHERE id >= ? AND body LIKE '{\"$device\"%' GROUP BY device)", (row_id,))
        return {d: json.loads(b)["$device"] for d, b in cur}

    def meta(self, key: str, default: int) -> int:
        row = self.db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return row[0] if row else default

    def set_meta(self, key: str, value: int) -> None:
        self.db.execute("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)", (key, value))

    def close(self) -> None:
        self.db.close()
