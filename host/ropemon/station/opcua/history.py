"""The OPC UA face's history: asyncua's history storage on each hoist's log (the rope tensions'
ReadRaw, the events table's rows as HistoryReadEvents), read through a read-only `Store`."""
from __future__ import annotations

import asyncio
import datetime
import logging
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ropemon.station.protocol import DAN_TO_N, L

if TYPE_CHECKING:
    from ropemon.station.opcua.face import OpcuaFace

log = logging.getLogger("ropemon.station.opcua")   # the face's one logger, as before it was a package

HISTORY_MAX_VALUES = 10_000  # values in one history-read answer; a continuation point gives the rest
#: the events columns a history event is made of (`Store.events` rows cut down to them)
EVENT_COLUMNS = ("id", "time_s", "action", "alarm", "kind", "node", "rope", "message", "operator")


class _History:
    """asyncua's history storage on each hoist's log: ReadRaw of the rope tensions, read from a
    read-only `Store` in its own thread (sqlite connections stay in one thread)."""

    def __init__(self, face: "OpcuaFace") -> None:
        self.face = face
        self.max_history_data_response_size = HISTORY_MAX_VALUES
        self.series: dict[Any, tuple[Path, int, int, str, float | None]] = {}  # NodeId -> db, node, rope, what, area
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="opcua-history")
        self._stores: dict[Path, Any] = {}

    async def init(self) -> None:
        pass

    async def new_historized_node(self, node_id: Any, period: Any, count: int = 0) -> None:
        pass

    async def save_node_value(self, node_id: Any, datavalue: Any) -> None:
        pass

    async def new_historized_event(self, source_id: Any, evtypes: Any, period: Any, count: int = 0) -> None:
        pass

    async def save_event(self, event: Any) -> None:
        pass

    async def read_event_history(self, source_id: Any, start: Any, end: Any, nb_values: int, evfilter: Any):
        """HistoryReadEvents on the Server object (every hoist) or a hoist's object (its own): the
        rows of the hoists' logs' events table, as AlarmConditionType events (EVENT_HISTORY)."""
        from asyncua import ua
        face = self.face
        if source_id == ua.NodeId(ua.ObjectIds.Server):
            hoists = list(face.hoists.values())
        else:
            hoists = [h for h in face.hoists.values() if h.obj == source_id]
        hoists = [h for h in hoists if h.db_path is not None]
        if not hoists:
            return [], None
        span = _span(start, end, nb_values)
        if span is None:
            return [], None
        lo, hi, newest_first, want = span
        rows: list[tuple[str, dict]] = []
        for h in hoists:
            got = await asyncio.get_running_loop().run_in_executor(
                self._pool, self._event_rows, h.db_path, lo, hi, want + 1, newest_first)
            rows += [(h.id, r) for r in got]
        rows.sort(key=lambda x: (x[1]["time_s"], x[0], x[1]["id"]), reverse=newest_first)
        cont = None
        if len(rows) > want and not (nb_values and nb_values <= HISTORY_MAX_VALUES):
            cont = _utc(rows[want][1]["time_s"])
        return [face._history_event(face.hoists[hid], r) for hid, r in rows[:want]], cont

    def _event_rows(self, db: Path, lo: float | None, hi: float | None, limit: int, newest_first: bool) -> list:
        store = self._open(db)
        if store is None:
            return []
        rows = store.events(since=lo, until=hi, by_time=True, newest_first=newest_first, limit=limit)
        return [{c: r[c] for c in EVENT_COLUMNS if c in r} for r in rows]

    async def stop(self) -> None:
        self._pool.submit(self._close).result()
        self._pool.shutdown()

    def _close(self) -> None:
        for s in self._stores.values():
            s.close()
        self._stores.clear()

    async def read_node_history(self, node_id: Any, start: Any, end: Any, nb_values: int):
        spec = self.series.get(node_id)
        if spec is None:
            return [], None
        span = _span(start, end, nb_values)
        if span is None:
            return [], None
        lo, hi, newest_first, want = span
        rows = await asyncio.get_running_loop().run_in_executor(
            self._pool, self._query, spec, lo, hi, want + 1, newest_first)
        cont = None
        if len(rows) > want and not (nb_values and nb_values <= HISTORY_MAX_VALUES):
            cont = _utc(rows[want][0])
        rows = rows[:want]
        _, _, _, what, area = spec
        return [_history_value(what, area, rx, mean, raw) for rx, mean, raw in rows], cont

    def _open(self, db: Path) -> Any:
        from ropemon.station.store import Store, StoreError
        store = self._stores.get(db)
        if store is None:
            if not db.exists():
                return None
            try:
                store = self._stores[db] = Store(db, readonly=True)
            except StoreError as e:
                log.warning("history: %s", e)
                return None
        return store

    def _query(self, spec: tuple, lo: float | None, hi: float | None, limit: int, newest_first: bool) -> list:
        db, node, rope, _, _ = spec
        store = self._open(db)
        if store is None:
            return []
        return store.rope_series(node, rope, lo, hi, limit, newest_first)


def _span(start: Any, end: Any, nb_values: int) -> tuple[float | None, float | None, bool, int] | None:
    """A history read's (lo, hi, newest first, how many) from OPC UA's start, end and count
    (an unset time is the Windows epoch); None when neither time is set (nothing to read)."""
    from asyncua import ua
    epoch = ua.get_win_epoch()
    t0 = None if start is None or start == epoch else start.timestamp()
    t1 = None if end is None or end == epoch else end.timestamp()
    if t0 is None and t1 is None:
        return None
    newest_first = t0 is None or (t1 is not None and t0 > t1)
    lo, hi = (t1, t0) if (t0 is not None and t1 is not None and t0 > t1) else (t0, t1)
    return lo, hi, newest_first, min(nb_values or HISTORY_MAX_VALUES, HISTORY_MAX_VALUES)


def _utc(t: float) -> datetime.datetime:
    return datetime.datetime.fromtimestamp(t, datetime.timezone.utc)


def _history_value(what: str, area: float | None, rx: float, mean_dan: int, raw_kpa: int) -> Any:
    from asyncua import ua
    ts = _utc(rx)
    if what == "Tension":
        v = None if mean_dan == L.TENSION_ABSENT else mean_dan * DAN_TO_N / 1000.0
    else:
        v = None if raw_kpa == L.RAW_KPA_ABSENT or area is None else raw_kpa * area
    if v is None:
        return ua.DataValue(StatusCode=ua.StatusCode(ua.StatusCodes.BadSensorFailure), SourceTimestamp=ts,
                            ServerTimestamp=ts)
    return ua.DataValue(ua.Variant(v, ua.VariantType.Double), SourceTimestamp=ts, ServerTimestamp=ts)
