"""`ropemon monitor`: the hoist-room live dashboard from one or more receiver ports.

Bytes from each receiver -> decoder -> merger (duplicates dropped) -> alarms,
SQLite log and the view. The view fits an 80x24 terminal (ssh from the hoist
room): per rope compensated and raw tension, deviation from the mean, a trend,
total load against rated, alarms (with the terminal bell), link quality per
receiver and the node's battery. Key `a` acknowledges the alarms, `n` shows
the next cage node (each cage has its own), `r` then `y` accepts a node refused
because its boot counter went back (logged with who and when), `q` quits.
"""
from __future__ import annotations

import argparse
import datetime
import getpass
import json
import os
import select
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from rich import box
from rich.console import Console, Group, RenderableType
from rich.table import Table
from rich.text import Text

from ropemon.station.alarms import ActiveAlarm, AlarmEngine, AlarmEvent, AlarmSettings
from ropemon.station.decode_cli import node_id
from ropemon.station.decoder import DUPLICATE_MEMORY, SEQ_COUNT_BITS, StreamDecoder
from ropemon.station.link import DEFAULT_BAUDRATE, FrameHub
from ropemon.station.protocol import DAN_TO_N, Frame, L, keys_from_options
from ropemon.station.uncertainty import BandParams, DeviationBand

TENSION_ABSENT = L.TENSION_ABSENT   # a rope whose sensor failed for the whole window

SPARK = "▁▂▃▄▅▆▇█"
TREND_LEN = 24           # frames in the sparkline (2.4 s at 10 frames/s)
BELL_REPEAT_S = 5.0      # ring again while an alarm stays unacknowledged


def sparkline(values: Iterable[float], lo: float, hi: float) -> str:
    """One block character per value, scaled between lo and hi."""
    span = hi - lo
    out = []
    for v in values:
        k = 0 if span <= 0 else int((v - lo) / span * (len(SPARK) - 1) + 0.5)
        out.append(SPARK[max(0, min(len(SPARK) - 1, k))])
    return "".join(out)


@dataclass
class SiteFigures:
    """What the view needs to know about the hoist beyond the frames."""

    cylinder_area_m2: list[float] = field(default_factory=list)  # per rope; empty: raw shown in kPa
    rated_rope_tension_n: float | None = None
    rated_load_n: float | None = None        # total of all ropes; default ropes x rated rope
    imbalance_frac: float = 0.10
    battery_low_v: float | None = None
    conveyance_weight_n: float | None = None  # weight of the empty cage alone; None: no slack alarm
    slack_frac: float = 0.60                 # slack below this share of a rope's part of conveyance_weight_n
    overload_frac: float = 1.0               # overload above this share of rated_load_n
    band: BandParams | None = None           # the seal's friction lines: each rope's band (ropemon.station.uncertainty)

    @classmethod
    def from_node_json(cls, path: str | Path) -> "SiteFigures":
        """The figures from a node.json's `physical` section (docs/config.md)."""
        try:
            phys = json.loads(Path(path).read_text())["physical"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise ValueError(f"{path}: cannot read the physical section of a node config: {e}") from None
        area = phys.get("cylinder_area_m2", [])
        ropes = int(phys.get("ropes", len(area) if isinstance(area, list) else 4))
        if not isinstance(area, list):
            area = [float(area)] * ropes
        rated = phys.get("rated_rope_tension_N")
        empty = phys.get("conveyance_weight_N")
        if empty is not None and (isinstance(empty, bool) or not isinstance(empty, (int, float))
                                  or not empty > 0):
            raise ValueError(f"{path}: physical.conveyance_weight_N: {empty!r} is not a positive load in N")
        slack_frac = phys.get("slack_frac", 0.60)
        if isinstance(slack_frac, bool) or not isinstance(slack_frac, (int, float)) or not 0 < slack_frac < 1:
            raise ValueError(f"{path}: physical.slack_frac: {slack_frac!r} is not a fraction between 0 and 1")
        rated_load = phys.get("rated_load_N", float(rated) * ropes if rated is not None else None)
        if rated_load is not None and (isinstance(rated_load, bool) or not isinstance(rated_load, (int, float))
                                       or not rated_load > 0):
            raise ValueError(f"{path}: physical.rated_load_N: {rated_load!r} is not a positive load in N")
        overload_frac = phys.get("overload_frac", 1.0)
        if isinstance(overload_frac, bool) or not isinstance(overload_frac, (int, float)) or not overload_frac >= 1:
            raise ValueError(f"{path}: physical.overload_frac: {overload_frac!r} is not a factor >= 1")
        try:
            band = BandParams.from_physical(phys)
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None
        return cls(
            band=band,
            cylinder_area_m2=[float(a) for a in area],
            rated_rope_tension_n=float(rated) if rated is not None else None,
            rated_load_n=float(rated_load) if rated_load is not None else None,
            imbalance_frac=float(phys.get("imbalance_frac", 0.10)),
            battery_low_v=phys.get("battery_low_V"),
            conveyance_weight_n=float(empty) if empty is not None else None,
            slack_frac=float(slack_frac),
            overload_frac=float(overload_frac),
        )


@dataclass
class NodeView:
    """What the view remembers of one cage node."""

    last: Frame
    last_at_s: float
    trend: list[deque[float]] = field(default_factory=list)


class MonitorView:
    """The operator's picture of the hoist, updated by merged frames, drawn by `render`.

    Each cage carries its own node; the view shows one node at a time (key `n`
    switches) and a line on the others, so two cages still fit 80x24.
    """

    def __init__(self, site: SiteFigures | None = None, trend_len: int = TREND_LEN) -> None:
        self.site = site or SiteFigures()
        self.nodes: dict[int, NodeView] = {}
        self.shown: int | None = None
        self.trend_len = trend_len
        self.link_rows: list[tuple[str, str]] = []   # (receiver, figures text)
        self.merge_text = ""
        self.alarm_rows: list[tuple[str, bool]] = []  # (text, acknowledged)
        self.refused: dict[int, tuple[int, int]] = {}  # node -> (newest boot, refused boot)
        self.bands: dict[int, list[DeviationBand | None]] = {}  # node -> per rope deviation and band
        self.confirm_accept: int | None = None  # node awaiting the operator's `y`
        self.frames = 0

    def on_frame(self, frame: Frame, now_s: float) -> None:
        """A new (merged, not duplicate) frame."""
        self.frames += 1
        nv = self.nodes.get(frame.node)
        if nv is None:
            nv = self.nodes[frame.node] = NodeView(frame, now_s)
            if self.shown is None:
                self.shown = frame.node
        nv.last, nv.last_at_s = frame, now_s
        if frame.ropes:
            while len(nv.trend) < len(frame.ropes):
                nv.trend.append(deque(maxlen=self.trend_len))
            for i, r in enumerate(frame.ropes):
                if r.mean_dan != TENSION_ABSENT:
                    nv.trend[i].append(r.mean_dan * DAN_TO_N)

    def next_node(self) -> None:
        """Show the next node (key `n`)."""
        ids = sorted(self.nodes)
        if ids:
            k = ids.index(self.shown) + 1 if self.shown in ids else 0
            self.shown = ids[k % len(ids)]

    @property
    def _node(self) -> NodeView | None:
        return self.nodes.get(self.shown) if self.shown is not None else None

    @property
    def last(self) -> Frame | None:
        nv = self._node
        return nv.last if nv else None

    @property
    def last_at_s(self) -> float | None:
        nv = self._node
        return nv.last_at_s if nv else None

    @property
    def trend(self) -> list[deque[float]]:
        nv = self._node
        return nv.trend if nv else []

    # -- figures ------------------------------------------------------------
    def raw_n(self, rope: int, raw_kpa: int) -> float | None:
        """Uncompensated tension p_tap x A, None without the cylinder area."""
        a = self.site.cylinder_area_m2
        if rope < len(a):
            return raw_kpa * 1000.0 * a[rope]
        return None

    # -- drawing ------------------------------------------------------------
    def render(self, now_s: float) -> RenderableType:
        parts: list[RenderableType] = [self._header(now_s), self._ropes()]
        if len(self.nodes) > 1:
            parts.append(self._others(now_s))
        keys = "a: acknowledge alarms   " + ("n: next node   " if len(self.nodes) > 1 else "") + "q: quit"
        parts += [self._alarms(), self._links()]
        if self.refused:
            parts.append(self._refused())
        parts.append(Text(keys, style="dim"))
        return Group(*parts)

    def _refused(self) -> Text:
        """Nodes refused for a boot counter gone back, and how the operator accepts one."""
        node = min(self.refused)
        top, boot = self.refused[node]
        t = Text(f" NODE {node} REFUSED: boot counter went back {top} -> {boot}", style="bold red reverse")
        if self.confirm_accept is not None:
            t.append(f"\n accept node {self.confirm_accept} as reset (wiped/replaced)? y: yes, any other key: no",
                     style="bold yellow")
        else:
            t.append(f"\n a replay, or the node lost its counter: check it, then r: accept node {node}",
                     style="yellow")
        return t

    def _others(self, now_s: float) -> Text:
        t = Text(" other nodes:", style="bold")
        for node, nv in sorted(self.nodes.items()):
            if node == self.shown:
                continue
            f = nv.last
            used = [r.mean_dan for r in f.ropes if r.mean_dan != TENSION_ABSENT]
            total = f"{sum(used) * DAN_TO_N / 1000:.1f} kN" if used else "no tension"
            t.append(f"  node {node}: {total}, {f.depth_mm / 1000:.0f} m, {now_s - nv.last_at_s:.1f} s ago")
        return t

    def _header(self, now_s: float) -> Text:
        t = Text()
        t.append(" ROPEMON ", style="bold reverse")
        f = self.last
        if f is None:
            t.append("  waiting for frames ...", style="yellow")
            return t
        age = now_s - (self.last_at_s or now_s)
        t.append(f" node {f.node} seq {f.seq} t {f.time_ms / 1000:.1f}s")
        t.append(f"  depth {f.depth_mm / 1000:6.1f} m  speed {f.speed_mm_s / 1000:+5.2f} m/s")
        bat_v = f.battery_mv / 1000
        low = self.site.battery_low_v is not None and bat_v < self.site.battery_low_v
        t.append("\n")
        t.append(f" battery {bat_v:.2f} V", style="bold red" if low else "")
        temp = f.oil_temp_c
        t.append(f"  oil {temp:.1f} C" if temp is not None else "  oil -- C")
        t.append(f"  last frame {age:4.1f} s ago", style="bold red reverse" if age > 2.0 else "")
        flags = [n for n in f.status_flags if n != "temp_absent"]
        if flags:
            t.append("  " + " ".join(flags), style="bold yellow")
        return t

    def _ropes(self) -> Table:
        kn = "kN"
        table = Table(box=box.SIMPLE_HEAD, padding=(0, 1), pad_edge=False, expand=False,
                      show_edge=False)
        table.add_column("rope", justify="right")
        table.add_column(f"comp {kn}", justify="right")
        table.add_column(f"raw {kn}", justify="right")
        table.add_column("dev %", justify="right", no_wrap=True)
        table.add_column(f"min..max {kn}", justify="right")
        table.add_column(f"trend ({self.trend_len / 10:.1f} s)", justify="left", no_wrap=True)
        f = self.last
        if f is None or not f.ropes:
            why = "no frame yet" if f is None else "STATUS ONLY: node not compensating"
            table.add_row("-", "-", "-", "-", "-", Text(why, style="bold red" if f else "yellow"))
            return table
        ok = [r.mean_dan != TENSION_ABSENT for r in f.ropes]
        comp = [r.mean_dan * DAN_TO_N if good else 0 for r, good in zip(f.ropes, ok)]
        used = [c for c, good in zip(comp, ok) if good]
        mean = sum(used) / len(used) if used else 0.0
        lim = self.site.imbalance_frac
        bands = self.bands.get(f.node, [])
        # Each rope on its own scale (the shape of its last seconds), but never
        # finer than 1 % of rated, so sensor noise does not look like a swing.
        min_span = 0.01 * (self.site.rated_rope_tension_n or max(comp) or 1.0)
        raw_sum = 0.0
        raw_ok = True
        for i, r in enumerate(f.ropes):
            if not ok[i]:
                table.add_row(str(i + 1), Text("FAULT", style="bold red reverse"), "-", "-", "-",
                              Text("sensor failed: no tension", style="bold red"))
                raw_ok = False
                continue
            dev = (comp[i] - mean) / mean if mean > 0 else 0.0
            band = bands[i] if i < len(bands) else None
            reach = band.reach if band is not None else abs(dev)
            style = "bold red reverse" if abs(dev) > lim else ("yellow" if abs(dev) > 0.8 * lim or reach >= lim else "")
            dev_txt = f"{dev * 100:+.1f}" + (f" +-{band.band * 100:.1f}" if band is not None else "")
            raw = self.raw_n(i, r.raw_kpa)
            if raw is None:
                raw_ok = False
                raw_txt = f"{r.raw_kpa}kPa"
            else:
                raw_sum += raw
                raw_txt = f"{raw / 1000:.1f}"
            table.add_row(str(i + 1), f"{comp[i] / 1000:.1f}", raw_txt, Text(dev_txt, style=style),
                          f"{r.min_dan * DAN_TO_N / 1000:.1f}..{r.max_dan * DAN_TO_N / 1000:.1f}",
                          self._spark(i, min_span))
        total = sum(used)
        rated = self.site.rated_load_n
        load = Text(f"load of rated {rated / 1000:.0f} kN: {total / rated * 100:.0f} %" if rated else "")
        if rated and total > rated:
            load.stylize("bold red reverse")
        if not all(ok):
            load = Text(f"{ok.count(False)} rope(s) missing from the sum", style="bold red")
        table.add_row("sum", Text(f"{total / 1000:.1f}", style="bold"),
                      f"{raw_sum / 1000:.1f}" if raw_ok else "-", "", "", load)
        return table

    def _spark(self, rope: int, min_span: float) -> str:
        if rope >= len(self.trend) or not self.trend[rope]:
            return ""
        d = self.trend[rope]
        lo, hi = min(d), max(d)
        mid, half = (lo + hi) / 2, max(hi - lo, min_span) / 2
        return sparkline(d, mid - half, mid + half)

    def _alarms(self) -> Text:
        t = Text()
        if not self.alarm_rows:
            t.append(" alarms: none", style="green")
            return t
        only_warnings = all(is_warning(text) for text, _ in self.alarm_rows)
        t.append(" ALARMS", style="bold yellow reverse" if only_warnings else "bold red reverse")
        shown = self.alarm_rows[:5]
        for text, acked in shown:
            t.append("\n ")
            new_style = "bold yellow" if is_warning(text) else "bold red"
            t.append(("  ack " if acked else "! NEW ") + text[:70],
                     style="yellow" if acked else new_style)
        if len(self.alarm_rows) > len(shown):
            t.append(f"\n  ... and {len(self.alarm_rows) - len(shown)} more")
        return t

    def _links(self) -> Text:
        t = Text(" link ", style="bold")
        parts = [f"{name}: {fig}" for name, fig in self.link_rows] or ["no receiver data"]
        t.append("  ".join(parts))
        if self.merge_text:
            t.append("\n      " + self.merge_text)
        return t


def link_figures(merger_stats: dict, counts: dict[str, Any], down: dict[str, str] | None = None,
                 errors: dict[str, tuple[int, str | None]] | None = None) -> list[tuple[str, str]]:
    """Per receiver: share of the node's frames it delivered, and its rejects;
    `down` names the receivers whose port is not open (with the reason); `errors`
    those whose decoder or consumer raised (count, last error): bytes were lost there."""
    rows = []
    down = down or {}
    errors = errors or {}
    names = list(counts)
    for node_stats in merger_stats.values():
        for r in node_stats["receivers"]:
            if r not in names:
                names.append(r)
    for name in names:
        shares = [s["receivers"][name]["share"] for s in merger_stats.values()
                  if name in s["receivers"] and s["receivers"][name]["share"] is not None]
        share = f"{100 * sum(shares) / len(shares):.0f} %" if shares else "-- %"
        c = counts.get(name)
        bad = f" crc {c.crc_fail} bad {c.malformed + c.mac_fail + c.replayed}" if c is not None else ""
        state = "  PORT DOWN" if name in down else ""
        if errors.get(name, (0, None))[0]:
            n, last = errors[name]
            state += f"  ERRORS {n}: {(last or '?')[:48]}"
        rows.append((name, share + bad + state))
    return rows


def merge_figures(merger_stats: dict) -> str:
    unique = sum(s["unique"] for s in merger_stats.values())
    lost = sum(s["lost"] for s in merger_stats.values())
    dup = sum(s["duplicates"] for s in merger_stats.values())
    sent = unique + lost
    pct = f" ({100 * lost / sent:.1f} %)" if sent else ""
    return f"frames {unique}  lost {lost}{pct}  duplicates dropped {dup}"


def is_warning(text: str) -> bool:
    """An alarm row of a warning (shown in yellow, after the alarms): DEVIATION POSSIBLE."""
    return text.startswith("DEVIATION POSSIBLE")


def alarm_text(a: ActiveAlarm) -> str:
    """One line for the operator; ropes numbered from 1 as on the cage."""
    rope = f" rope {a.rope + 1}" if a.rope is not None else ""
    v, thr = a.value, a.threshold
    if a.kind == "deviation" and v is not None and thr is not None:
        what = f"{v * 100:+.1f} % from mean (limit {thr * 100:.0f} %)"
    elif a.kind == "deviation_possible" and v is not None and thr is not None and a.band is not None:
        what = f"{v * 100:+.1f} % +-{a.band * 100:.1f} from mean: may reach {thr * 100:.0f} %"
    elif a.kind == "overload" and v is not None and thr is not None:
        what = f"total {v * DAN_TO_N / 1000:.1f} kN > {thr * DAN_TO_N / 1000:.1f} kN"
    elif a.kind == "slack" and v is not None and thr is not None:
        what = f"{v * DAN_TO_N / 1000:.1f} kN < {thr * DAN_TO_N / 1000:.1f} kN"
    elif a.kind == "battery_low" and v is not None:
        what = f"{v / 1000:.2f} V"
    elif a.kind == "silent" and v is not None:
        what = f"no frame for {v:.1f} s"
    else:
        what = a.message
    state = "" if a.present else " (cleared)"
    return f"{a.kind.upper().replace('_', ' ')}{rope}: {what}{state}"


class HostSession:
    """The host's data path: receivers -> `FrameHub` (decode, merge) -> alarms, log, view.

    Reader threads decode and merge (the hub); `pump`, on the main loop's
    thread, which also owns the SQLite store, consumes the merged frames.
    Only new frames (not duplicates) reach the alarms, the log and the view.

    With keys and a store that already holds frames, the replay protection
    resumes from the log before any receiver is read (`resumed`): a frame at or
    below the last one logged for its node is a replay (or a duplicate of one of
    the last frames), as if the host had not stopped. A new baseline taken on an
    operator-accepted rewind is logged (`rebase` event) so that a restart resumes
    from it, not from the node's older, higher sequence numbers.
    """

    LINK_LOG_S = 10.0   # link statistics go to the log this often

    def __init__(self, keys: dict[int, bytes] | None = None, settings: AlarmSettings | None = None,
                 store: Any = None, view: MonitorView | None = None,
                 clock: Callable[[], float] = time.monotonic, accept_rewound: Iterable[int] = ()) -> None:
        self.keys = keys
        self.hub = FrameHub(keys, accept_rewound=accept_rewound)
        self.alarms = AlarmEngine(settings)
        self.store = store
        self.view = view
        self.clock = clock
        self.new_raises = 0          # raise events since the view last rang the bell
        self.frames: list[Frame] = []
        self.keep_frames = False     # the demo keeps them to compare with the truth
        self._feeders: dict[str, Callable[[bytes], None]] = {}
        self._link_logged_s: float | None = None
        self._link_errors_logged: dict[str, int] = {}  # receiver -> callback_errors already logged
        self._rebase_logged: dict[int, int] = {}        # node -> seq of the last baseline logged
        self.resumed: dict[int, int] = {}               # node -> last seq logged, resumed from the store
        if store is not None and keys:
            self.resumed = {n: seq for n, seq in store.last_seqs().items() if n in keys}
            self.hub.seed(self.resumed, {n: store.recent_frames(n, DUPLICATE_MEMORY) for n in self.resumed})

    def resumed_text(self) -> str | None:
        """One line saying where the replay protection resumed from (None: nothing logged before)."""
        if not self.resumed:
            return None
        nodes = ", ".join(f"node {n} at boot {seq >> SEQ_COUNT_BITS} count {seq & ((1 << SEQ_COUNT_BITS) - 1)}"
                          for n, seq in sorted(self.resumed.items()))
        return f"resumed replay protection from the log: {nodes}"

    @property
    def decoders(self) -> dict[str, StreamDecoder]:
        return self.hub.decoders

    def add_receiver(self, name: str) -> Callable[[bytes], None]:
        """The byte sink of receiver `name` (thread-safe: decodes and merges)."""
        if name not in self._feeders:
            self._feeders[name] = self.hub.feeder(name)
        return self._feeders[name]

    def add_port(self, url: str, name: str, **kw: Any) -> Any:
        """Read receiver `name` from a serial port (pyserial URL); returns the SerialReceiver."""
        rx = self.hub.add_port(url, name, **kw)
        self._feeders[name] = rx.on_bytes
        return rx

    def feed(self, receiver: str, data: bytes) -> None:
        """Bytes of one receiver, processed at once (tests, captures)."""
        self.add_receiver(receiver)(data)
        self.pump()

    def pump(self) -> int:
        """Consume every merged frame the hub has queued; return how many."""
        n = 0
        while True:
            item = self.hub.get(timeout=0)
            if item is None:
                break
            n += 1
            if item.is_new:
                f = item.frame
                now = self.clock()
                self._events(self.alarms.update(f, now))
                if self.store is not None:
                    self.store.add_frame(item.receiver, f, item.rx_time)
                if self.keep_frames:
                    self.frames.append(f)
                if self.view is not None:
                    self.view.on_frame(f, now)
                    self.view.bands[f.node] = self.alarms.deviation_bands(f.node)
            if item.rebased_from is not None:
                self._log_rebase(item)
        if self.keys:
            now = self.clock()
            for name, dec in list(self.hub.decoders.items()):
                c = dec.counts
                self._events(self.alarms.update_link(name, c.mac_fail, c.replayed, now))
        return n

    def tick(self) -> None:
        """Time passes: silent alarm, store flush and link log, view figures."""
        now = self.clock()
        self._events(self.alarms.tick(now))
        if self.store is not None:
            self.store.flush()
            if self._link_logged_s is None or now - self._link_logged_s >= self.LINK_LOG_S:
                self.log_link_stats()
                self._link_logged_s = now
        self._refresh_view()

    def ack_all(self) -> None:
        self._events(self.alarms.ack("*", self.clock()))
        self._refresh_view()

    def accept_rewound(self, node: int, operator: str, how: str = "interactively") -> AlarmEvent:
        """The operator accepts `node` although its boot counter went back: every receiver
        takes its next authenticated frame as the new baseline. Logged (who, when, which
        node) as an `accept` event: it decides whether frames are trusted."""
        refused = self.hub.rewound().get(node)
        self.hub.accept_rewound(node)
        if self.view is not None and self.view.confirm_accept == node:
            self.view.confirm_accept = None
        wall = time.time()
        when = datetime.datetime.fromtimestamp(wall, datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
        was = f" (boot counter went back {refused[0]} -> {refused[1]})" if refused else ""
        ev = AlarmEvent(wall, "accept", f"rewound:n{node}", "rewound", node, None,
                        refused[0] if refused else None, refused[1] if refused else None,
                        f"operator {operator} accepted node {node}{was} {how} at {when}")
        if self.store is not None:
            self.store.add_event(ev)
        self._refresh_view()
        return ev

    def _log_rebase(self, item: Any) -> None:
        """A receiver took an accepted node's frame of an older boot as its new baseline:
        logged after that frame (`rebase` event; the receivers of one node log it once),
        so that a restart resumes the replay protection from this sequence."""
        f, prev = item.frame, item.rebased_from
        if self.store is None or self._rebase_logged.get(f.node) == f.seq:
            return
        self._rebase_logged[f.node] = f.seq
        mask = (1 << SEQ_COUNT_BITS) - 1
        self.store.add_event(AlarmEvent(
            time.time(), "rebase", f"rewound:n{f.node}", "rewound", f.node, None, f.seq, prev,
            f"node {f.node}: boot {f.seq >> SEQ_COUNT_BITS} count {f.seq & mask} taken as its new baseline "
            f"(was boot {prev >> SEQ_COUNT_BITS} count {prev & mask}; receiver {item.receiver})"))

    def link_errors(self) -> dict[str, tuple[int, str | None]]:
        """Receivers whose decoder or consumer raised: {name: (count, last error)}."""
        return {n: (r.callback_errors, r.last_callback_error)
                for n, r in list(self.hub.receivers.items()) if r.callback_errors}

    def log_link_stats(self) -> None:
        """Decoder counts and merge shares of every receiver into the store, and a
        `link_error` event for a receiver whose decoder or consumer raised since the
        last log (link_stats has no text column: the event carries the message)."""
        if self.store is None:
            return
        t = time.time()
        for name, (n, last) in self.link_errors().items():
            if n > self._link_errors_logged.get(name, 0):
                self.store.add_event(AlarmEvent(
                    t, "error", f"link_error:{name}", "link_error", None, None, n, None,
                    f"receiver {name}: {n} decoder/consumer errors (bytes lost), last: {last}"))
                self._link_errors_logged[name] = n
        stats = self.hub.merge_stats()
        for name, dec in list(self.decoders.items()):
            self.store.add_link_stats(t, name, dec.counts.as_dict())
            for node, st in stats.items():
                r = st["receivers"].get(name)
                if r is not None:
                    self.store.add_link_stats(t, name, None, node, {
                        "delivered": r["delivered"], "share": r["share"],
                        "lost": st["lost"], "duplicates": st["duplicates"]})

    def close(self) -> None:
        """Stop the ports, process what is queued, log the link figures, commit."""
        self.hub.stop()
        self.pump()
        if self.store is not None:
            self.log_link_stats()
            self.store.commit()

    def _events(self, events: list[AlarmEvent]) -> None:
        for e in events:
            if e.action == "raise":
                self.new_raises += 1
            if self.store is not None:
                self.store.add_event(e)

    def _refresh_view(self) -> None:
        if self.view is None:
            return
        stats = self.hub.merge_stats()
        down = {n: r.last_error or "not open" for n, r in list(self.hub.receivers.items()) if not r.connected}
        self.view.link_rows = link_figures(stats, {n: d.counts for n, d in list(self.decoders.items())}, down,
                                           self.link_errors())
        self.view.merge_text = merge_figures(stats)
        if not self.keys:
            self.view.merge_text += "  NO KEY: not authenticated"
        if self.hub.dropped:
            self.view.merge_text += f"  HOST OVERLOADED: {self.hub.dropped} frames not processed"
        self.view.alarm_rows = [(alarm_text(a), not a.latched) for a in self.alarms.active()]
        now = self.clock()
        for node in self.view.nodes:
            self.view.bands[node] = self.alarms.deviation_bands(node, now)
        self.view.refused = self.hub.rewound()
        if self.view.confirm_accept not in self.view.refused:
            self.view.confirm_accept = None


# -- the command -------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", action="append", required=True, metavar="URL",
                   help="receiver serial port (device path or pyserial URL); give twice for two receivers; "
                        "NAME=URL names the receiver")
    p.add_argument("--db", help="SQLite log to append frames and alarm events to")
    p.add_argument("--config", action="append", default=[], metavar="NODE.JSON",
                   help="node.json: cylinder areas, rated tension, alarm thresholds and the node key "
                        "(repeatable, one per node of the same hoist; merged with --key)")
    p.add_argument("--key", action="append", default=[], metavar="NODE:HEX",
                   help="HMAC key of a node (repeatable); without keys authenticity is not checked")
    p.add_argument("--accept-rewound", action="append", type=node_id, default=[], metavar="NODE",
                   help="operator decision: NODE's boot counter really went back (flash wiped or replaced); "
                        "take its next authenticated frame as its new baseline (repeatable; logged)")
    p.add_argument("--baud", type=int, default=DEFAULT_BAUDRATE,
                   help=f"baud rate of the receiver lines (default {DEFAULT_BAUDRATE})")
    p.add_argument("--rs485", action="store_true",
                   help="half-duplex RS485 mode for adapters whose driver needs it (RTS switching)")
    p.add_argument("--refresh-hz", type=float, default=4.0, help="screen refreshes per second")
    p.add_argument("--silent-s", type=float, default=5.0, help="node-silent alarm after this many seconds")


def receiver_names(ports: list[str]) -> list[tuple[str, str]]:
    """[(name, url)]: `NAME=URL` or default names pithead, mid-shaft, rx3, ..."""
    default = ["pithead", "mid-shaft"]
    out = []
    for i, spec in enumerate(ports):
        name, sep, url = spec.partition("=")
        if not sep or "://" in name or name.startswith("/"):
            name, url = (default[i] if i < len(default) else f"rx{i + 1}"), spec
        out.append((name, url))
    return out


def site_from_configs(paths: list[str]) -> SiteFigures:
    """The hoist's figures from its node.json files (defaults without any). The view and the
    alarms use one set of figures: node configs that disagree on them are refused."""
    figures = [(p, SiteFigures.from_node_json(p)) for p in paths]
    for p, f in figures[1:]:
        if f != figures[0][1]:
            raise ValueError(f"{p} and {figures[0][0]} describe different hoists (cylinder areas, rated "
                             "tension, loads or thresholds differ): run one monitor per hoist")
    return figures[0][1] if figures else SiteFigures()


def alarm_settings(site: SiteFigures, silent_s: float = 5.0) -> AlarmSettings:
    """Alarm thresholds from the node config's figures (regulation defaults otherwise).

    With the empty conveyance's weight (`physical.conveyance_weight_N`, written by `ropemon config`)
    the slack-rope alarm is on: a rope below `slack_frac` of its share of that load. With the seal's
    friction lines (`physical.friction`) each rope gets a band and DEVIATION POSSIBLE is on."""
    kw: dict[str, Any] = dict(
        deviation_frac=site.imbalance_frac,
        battery_low_mv=int(site.battery_low_v * 1000) if site.battery_low_v else None,
        silent_s=silent_s,
        overload_frac=site.overload_frac,
        band=site.band,
    )
    rated_dan = int(site.rated_load_n / DAN_TO_N) if site.rated_load_n else None
    n_ropes = len(site.cylinder_area_m2)
    if site.conveyance_weight_n and rated_dan and n_ropes:
        return AlarmSettings.from_loads(rated_dan, round(site.conveyance_weight_n / DAN_TO_N), n_ropes,
                                        slack_frac_of_empty=site.slack_frac, **kw)
    return AlarmSettings(rated_load_dan=rated_dan, **kw)


class KeyReader:
    """Single key presses from a terminal's stdin (cbreak mode), restored on exit."""

    def __init__(self) -> None:
        self.fd: int | None = None
        self._saved: Any = None
        if sys.stdin.isatty():
            import termios
            import tty
            self.fd = sys.stdin.fileno()
            self._saved = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)

    def read(self, timeout_s: float) -> str:
        if self.fd is None:
            time.sleep(timeout_s)
            return ""
        r, _, _ = select.select([self.fd], [], [], timeout_s)
        return os.read(self.fd, 16).decode(errors="ignore") if r else ""

    def close(self) -> None:
        if self.fd is not None:
            import termios
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            self.fd = None


def operator_name() -> str:
    """Who is at the keyboard, for the log: the login name, and the ssh client when remote."""
    try:
        who = getpass.getuser()
    except (OSError, KeyError):  # no login name in the environment or the password database
        who = f"uid {os.getuid()}"
    ssh = os.environ.get("SSH_CLIENT", "").split()
    return f"{who} (ssh from {ssh[0]})" if ssh else who


def handle_keys(session: HostSession, k: str, operator: str) -> bool:
    """Act on key presses; False when the operator quits. `r` asks to accept the first
    refused node, `y` confirms it, any other key cancels the question."""
    view = session.view
    assert view is not None
    k = k.lower()
    if "q" in k:
        return False
    if view.confirm_accept is not None:
        node, view.confirm_accept = view.confirm_accept, None
        if "y" in k:
            session.accept_rewound(node, operator)
        return True
    if "a" in k:
        session.ack_all()
    if "n" in k:
        view.next_node()
    if "r" in k and view.refused:
        view.confirm_accept = min(view.refused)
    return True


def live_loop(session: HostSession, console: Console, refresh_hz: float,
              done: Callable[[], bool] = lambda: False) -> None:
    """Draw the view until `q` or `done()`; `a` acknowledges, `r` `y` accepts a refused
    node; bell on new alarms."""
    from rich.live import Live

    view = session.view
    assert view is not None
    keys = KeyReader()
    operator = operator_name()
    last_bell = 0.0
    try:
        with Live(view.render(session.clock()), console=console, screen=console.is_terminal,
                  auto_refresh=False, transient=False) as live:
            while not done():
                k = keys.read(1.0 / refresh_hz)
                if k and not handle_keys(session, k, operator):
                    break
                session.pump()
                session.tick()
                now = session.clock()
                unacked = any(not acked for _, acked in view.alarm_rows)
                ring = session.new_raises > 0 or (unacked and now - last_bell > BELL_REPEAT_S)
                session.new_raises = 0
                live.update(view.render(now), refresh=True)
                if ring and (unacked or last_bell == 0.0):
                    console.bell()
                    last_bell = now
    finally:
        keys.close()


def run(args: argparse.Namespace) -> int:
    try:
        keys = keys_from_options(args.key, args.config, args.accept_rewound)
        site = site_from_configs(args.config)
    except ValueError as e:
        print(f"ropemon monitor: {e}", file=sys.stderr)
        return 2
    store = None
    if args.db:
        from ropemon.station.store import Store, StoreError
        try:
            store = Store(args.db)
        except StoreError as e:
            print(f"ropemon monitor: {e}", file=sys.stderr)
            return 2
    view = MonitorView(site)
    # Wall-clock time, like frames.rx_time: alarm raise/clear/ack times in the log must be
    # readable as times of day (a hoist-room PC slews its clock with NTP, it does not jump).
    session = HostSession(keys or None, alarm_settings(site, args.silent_s), store, view,
                          clock=time.time, accept_rewound=args.accept_rewound)
    resumed = session.resumed_text()
    if resumed is not None:
        print(f"ropemon monitor: {resumed}", file=sys.stderr)
    operator = operator_name()
    for node in args.accept_rewound:
        session.accept_rewound(node, operator, "with --accept-rewound")
    try:
        for name, url in receiver_names(args.port):
            session.add_port(url, name, baudrate=args.baud, rs485=args.rs485).start()
        live_loop(session, Console(), args.refresh_hz)
    finally:
        session.close()
        if store is not None:
            store.close()
    return 0
