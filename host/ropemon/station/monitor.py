"""`ropemon monitor`: the hoist-room live dashboard from one or more receiver ports.

The station (`ropemon.station.pipeline`: receivers -> decode, merge -> alarms,
SQLite log) with one more listener, `MonitorView`, and the keys. The view fits
an 80x24 terminal (ssh from the hoist room): per rope compensated and raw
tension, deviation from the mean, a trend, the piston in its stroke (where the
frames carry its position), total load against rated, the hoist's standing
status (the imbalance the seals can hide), alarms (with the terminal bell),
link quality per receiver and the node's battery.
Key `a` acknowledges the alarms, `s` shelves one (which, for how long, why:
each a digit; it returns by itself), `u` unshelves one, `n` shows the next cage
node (each cage has its own), `r` then `y` accepts a node refused because its
boot counter went back (logged with who and when), `q` quits. Keys become the
station's commands; any key not offered cancels a question.
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import getpass
import json
import os
import select
import signal
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import IO, Any, Callable, Iterable, Sequence

from rich import box
from rich.console import Console, Group, RenderableType
from rich.table import Table
from rich.text import Text

from ropemon.station.alarms import ActiveAlarm, AlarmEvent
from ropemon.station import assembly
from ropemon.station.assembly import HoistSpec, run_loop
from ropemon.station.decode_cli import add_key_arguments, node_id
from ropemon.station.link import DEFAULT_BAUDRATE, Received
from ropemon.station.pipeline import (AcceptRewound, Acknowledge, AlarmState, Listener, Shelve, HoistPipeline,
                                      StationStatus, Unshelve)
from ropemon.station.protocol import DAN_TO_N, Frame, L, keys_from_options
from ropemon.station.nodefigures import NodeFigures, alarm_settings, figures_from_configs
from ropemon.station.uncertainty import DeviationBand
from ropemon.station.views import (STALE_S, alarm_text, has_positions, is_warning, link_figures,
                                   merge_figures, piston)

TENSION_ABSENT = L.TENSION_ABSENT   # a rope whose sensor failed for the whole window

SPARK = "▁▂▃▄▅▆▇█"
TREND_LEN = 24           # frames in the sparkline (2.4 s at 10 frames/s)
GAUGE_CELLS = 9          # the stroke gauge's cells between its end stops
BELL_REPEAT_S = 5.0      # ring again while an alarm stays unacknowledged


def sparkline(values: Iterable[float], lo: float, hi: float) -> str:
    """One block character per value, scaled between lo and hi."""
    span = hi - lo
    out = []
    for v in values:
        k = 0 if span <= 0 else int((v - lo) / span * (len(SPARK) - 1) + 0.5)
        out.append(SPARK[max(0, min(len(SPARK) - 1, k))])
    return "".join(out)


def stroke_gauge(pos_m: float | None, stroke_m: float | None, margin_m: float | None,
                 cells: int = GAUGE_CELLS) -> str:
    """The piston in its cylinder on one line: `[` the retracted end stop (x = -stroke/2),
    `]` the extended one (x = +stroke/2, the rope pulling the piston out), `:` a cell within
    the stroke margin of an end, `·` the free stroke, `█` the piston's cell. "" without the
    stroke."""
    if not stroke_m or stroke_m <= 0:
        return ""
    half, step, m = stroke_m / 2, stroke_m / cells, max(margin_m or 0.0, 0.0)
    out = [":" if (k * step < m or (k + 1) * step > stroke_m - m) else "·" for k in range(cells)]
    if pos_m is not None:
        out[max(0, min(cells - 1, int((pos_m + half) // step)))] = "█"
    return "[" + "".join(out) + "]"


@dataclass
class NodeView:
    """What the view remembers of one cage node."""

    last: Frame
    last_at_s: float
    trend: list[deque[float]] = field(default_factory=list)


class MonitorView(Listener):
    """The operator's picture of the hoist: a station listener, drawn by `render`.

    Each cage carries its own node; the view shows one node at a time (key `n`
    switches) and a line on the others, so two cages still fit 80x24.
    """

    name = "terminal view"

    def __init__(self, figures: NodeFigures | None = None, trend_len: int = TREND_LEN) -> None:
        self.figures = figures or NodeFigures()
        self.nodes: dict[int, NodeView] = {}
        self.shown: int | None = None
        self.trend_len = trend_len
        self.link_rows: list[tuple[str, str]] = []   # (receiver, figures text)
        self.merge_text = ""
        self.alarm_rows: list[tuple[str, bool]] = []  # (text, acknowledged)
        self.refused: dict[int, tuple[int, int]] = {}  # node -> (newest boot, refused boot)
        self.bands: dict[int, list[DeviationBand | None]] = {}  # node -> per rope deviation and band
        self.hoist: dict[int, Any] = {}         # node -> the hoist's standing status (HoistStatus)
        self.confirm_accept: int | None = None  # node awaiting the operator's `y`
        self.alarms: list[ActiveAlarm] = []     # as alarm_rows, with their ids
        self.shelved: list[ActiveAlarm] = []    # shelved alarms, present or not
        self.question: Question | None = None   # a shelve or unshelve being asked
        self.frames = 0
        self.new_raises = 0     # raise events since the bell last rang

    # -- the station's messages -------------------------------------------------------
    def on_frame(self, item: Received, now_s: float) -> None:
        self.show_frame(item.frame, now_s)

    def on_event(self, event: AlarmEvent) -> None:
        if event.action == "raise":
            self.new_raises += 1

    def on_alarms(self, state: AlarmState) -> None:
        self.alarms = list(state.active)
        self.alarm_rows = [(alarm_text(a), not a.latched) for a in state.active]
        self.shelved = [a for a in state.hidden if a.shelved_until is not None]
        self.bands = dict(state.bands)
        self.hoist = dict(state.hoist)

    def on_status(self, status: StationStatus) -> None:
        down = {n: r.last_error or "not open" for n, r in status.receivers.items() if not r.connected}
        errors = {n: (r.callback_errors, r.last_callback_error)
                  for n, r in status.receivers.items() if r.callback_errors}
        self.link_rows = link_figures(status.merge, {n: r.counts for n, r in status.receivers.items()}, down,
                                      errors)
        self.merge_text = merge_figures(status.merge)
        if not status.authenticated:
            self.merge_text += "  NO KEY: not authenticated"
        if status.dropped:
            self.merge_text += f"  HOST OVERLOADED: {status.dropped} frames not processed"
        for name, (n, last) in status.listener_errors.items():
            self.merge_text += f"  {name.upper()} FAILED {n}x: {last[:40]}"
        self.refused = dict(status.rewound)
        if self.confirm_accept not in self.refused:
            self.confirm_accept = None

    def show_frame(self, frame: Frame, now_s: float) -> None:
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
        a = self.figures.cylinder_area_m2
        if rope < len(a):
            return raw_kpa * 1000.0 * a[rope]
        return None

    # -- drawing ------------------------------------------------------------
    def render(self, now_s: float) -> RenderableType:
        parts: list[RenderableType] = [self._header(now_s), self._ropes(now_s)]
        held = self.last.held_back if self.last is not None else ()
        if held:  # the node held these ropes' compensation back at rest (docs/operator.md)
            parts.append(Text(f" * rope {', '.join(str(i + 1) for i in held)}: held back at rest (piston travel)",
                              style="cyan"))
        status = self._hoist_status()
        if status is not None:
            parts.append(status)
        if len(self.nodes) > 1:
            parts.append(self._others(now_s))
        keys = ("a: acknowledge alarms   " + ("s: shelve   " if self.alarms else "")
                + ("u: unshelve   " if self.shelved else "") + ("n: next node   " if len(self.nodes) > 1 else "")
                + "q: quit")
        parts += [self._alarms(), self._links()]
        if self.refused:
            parts.append(self._refused())
        if self.question is not None:
            parts.append(Text(" " + self.question.text(), style="bold reverse"))
        else:
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
        low = self.figures.battery_low_v is not None and bat_v < self.figures.battery_low_v
        t.append("\n")
        t.append(f" battery {bat_v:.2f} V", style="bold red" if low else "")
        temp = f.oil_temp_c
        t.append(f"  oil {temp:.1f} C" if temp is not None else "  oil -- C")
        t.append(f"  last frame {age:4.1f} s ago", style="bold red reverse" if age > STALE_S else "")
        flags = " ".join(n for n in f.status_flags if n not in ("temp_absent", "held_back"))
        if flags:      # beside the figures where they fit, else on one line of their own
            room = 79 - len(t.plain.split("\n")[-1]) - 2
            t.append(("  " + flags) if len(flags) <= room else ("\n " + (flags if len(flags) <= 78 else
                                                                          flags[:77] + "…")), style="bold yellow")
        return t

    def _hoist_status(self) -> Text | None:
        """The hoist's standing status (the imbalance its seals can hide): a status, never an alarm."""
        st = self.hoist.get(self.shown) if self.shown is not None else None
        text = hoist_line(st) if st is not None else ""
        if not text:
            return None
        return Text(" hoist: " + (text if len(text) <= 71 else text[:70] + "…"), style="cyan")

    def _ropes(self, now_s: float | None = None) -> Table:
        kn = "kN"
        f = self.last
        # Frames with the pistons' positions: the stroke gauge takes the window's min..max
        # column (still on the web page, in the log and the export) and the columns close up,
        # so that the line still fits 80 characters.
        gauge = f is not None and has_positions(f)
        table = Table(box=box.SIMPLE_HEAD, padding=(0, 0) if gauge else (0, 1), pad_edge=False,
                      expand=False, show_edge=False)
        table.add_column("rope", justify="right")
        table.add_column(f"comp {kn}", justify="right")
        table.add_column(f"raw {kn}", justify="right")
        table.add_column("dev %", justify="right", no_wrap=True)
        if gauge:
            table.add_column("piston mm", justify="left", no_wrap=True)
        else:
            table.add_column(f"min..max {kn}", justify="right")
        table.add_column(f"trend ({self.trend_len / 10:.1f} s)", justify="left", no_wrap=True)
        if f is None or not f.ropes:
            why = "no frame yet" if f is None else "STATUS ONLY: node not compensating"
            table.add_row("-", "-", "-", "-", "-", Text(why, style="bold red" if f else "yellow"))
            return table
        age = 0.0 if now_s is None or self.last_at_s is None else now_s - self.last_at_s
        stale = age > STALE_S      # not current: greyed, never in the normal colours
        ok = [r.mean_dan != TENSION_ABSENT for r in f.ropes]
        comp = [r.mean_dan * DAN_TO_N if good else 0 for r, good in zip(f.ropes, ok)]
        used = [c for c, good in zip(comp, ok) if good]
        mean = sum(used) / len(used) if used else 0.0
        lim = self.figures.imbalance_frac
        bands = self.bands.get(f.node, [])
        # Each rope on its own scale (the shape of its last seconds), but never
        # finer than 1 % of rated, so sensor noise does not look like a swing.
        min_span = 0.01 * (self.figures.rated_rope_tension_n or max(comp) or 1.0)
        raw_sum = 0.0
        raw_ok = True
        held = f.held_back
        for i, r in enumerate(f.ropes):
            if not ok[i]:
                table.add_row(str(i + 1), Text("FAULT", style="bold red reverse"), "-", "-",
                              self._gauge(f, i) if gauge else "-",
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
            comp_txt = Text(f"{comp[i] / 1000:.1f}" + ("*" if i in held else ""), style="cyan" if i in held else "")
            table.add_row(str(i + 1), comp_txt, raw_txt, Text(dev_txt, style="dim" if stale else style),
                          self._gauge(f, i) if gauge else
                          f"{r.min_dan * DAN_TO_N / 1000:.1f}..{r.max_dan * DAN_TO_N / 1000:.1f}",
                          self._spark(i, min_span), style="dim" if stale else None)
        total = sum(used)
        rated = self.figures.rated_load_n
        load = Text(f"load of rated {rated / 1000:.0f} kN: {total / rated * 100:.0f} %" if rated else "")
        if rated and total > rated:
            load.stylize("bold red reverse")
        label = "sum"
        if not all(ok):
            missing = ", ".join(str(i + 1) for i, good in enumerate(ok) if not good)
            label = "part"           # not the total: never read as the hoist's load
            load = Text(f"PARTIAL SUM: rope {missing} missing", style="bold red")
        table.add_row(label, Text(f"{total / 1000:.1f}", style="bold"),
                      f"{raw_sum / 1000:.1f}" if raw_ok else "-", "", "", load, style="dim" if stale else None)
        if stale:
            table.add_row("", Text("STALE", style="bold red reverse"), "", "", "",
                          Text(f"last frame {age:.0f} s ago: not current", style="bold red"))
        return table

    def _gauge(self, f: Frame, rope: int) -> Text:
        """The stroke gauge of one rope and its position in mm (red: within the stroke margin)."""
        pos, fault, near = piston(f, rope)
        if fault:
            return Text("FAULT: displacement", style="bold red")
        if pos is None:
            return Text("no position", style="yellow")
        strokes = self.figures.stroke_m
        stroke = strokes[rope] if rope < len(strokes) else None
        margin = self.figures.stroke_margin_m
        bar = stroke_gauge(pos, stroke, margin)
        if stroke:
            m = margin or 0.0
            near = near or abs(pos) >= stroke / 2 - m
        return Text(f"{bar} {pos * 1000:+.1f}".lstrip(), style="bold red" if near else "")

    def _spark(self, rope: int, min_span: float) -> str:
        if rope >= len(self.trend) or not self.trend[rope]:
            return ""
        d = self.trend[rope]
        lo, hi = min(d), max(d)
        mid, half = (lo + hi) / 2, max(hi - lo, min_span) / 2
        return sparkline(d, mid - half, mid + half)

    def _alarms(self) -> Text:
        t = Text()
        if self.shelved:
            t.append(" shelved: " + "; ".join(shelved_text(a) for a in self.shelved)[:70] + "\n", style="yellow")
        if not self.alarm_rows:
            t.append(" alarms: none", style="green")
            return t
        only_warnings = all(is_warning(text) for text, _ in self.alarm_rows)
        t.append(" ALARMS", style="bold yellow reverse" if only_warnings else "bold red reverse")
        shown = self.alarm_rows[:SHOWN_ALARMS]
        numbered = self.question is not None and self.question.step == "which" and self.question.action == "shelve"
        for i, (text, acked) in enumerate(shown):
            t.append("\n ")
            new_style = "bold yellow" if is_warning(text) else "bold red"
            mark = f"{i + 1}) " if numbered else ""
            t.append(mark + ("  ack " if acked else "! NEW ") + text[:70 - len(mark)],
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


SHOWN_ALARMS = 5
SHELVE_MINUTES = (15, 60, 480)
SHELVE_REASONS = ("nuisance: chattering or standing in error", "sensor or loop under repair",
                  "hoist under maintenance")


@dataclass
class Question:
    """A shelve (which alarm, for how long, why) or an unshelve (which) being asked, one
    digit a step."""

    action: str                 # "shelve" or "unshelve"
    choices: list[ActiveAlarm]  # the alarms offered, numbered from 1
    step: str = "which"         # "which", "minutes", "reason"
    alarm: str = ""
    minutes: int = 0

    def text(self) -> str:
        if self.step == "which" and self.action == "shelve":
            return f"shelve which alarm? 1-{len(self.choices)} (numbered above), any other key: cancel"
        if self.step == "which":
            return "unshelve: " + "  ".join(f"{i + 1}) {a.id}" for i, a in enumerate(self.choices)) + "  other: cancel"
        if self.step == "minutes":
            return "for how long? " + "  ".join(f"{i + 1}) {_duration(m)}" for i, m in enumerate(SHELVE_MINUTES))
        return "why? " + "  ".join(f"{i + 1}) {r.split(':')[0]}" for i, r in enumerate(SHELVE_REASONS))


def _duration(minutes: int) -> str:
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h"


def shelved_text(a: ActiveAlarm) -> str:
    """One shelved alarm: what, until when (local time), why and who."""
    until = datetime.datetime.fromtimestamp(a.shelved_until).strftime("%H:%M") if a.shelved_until else "?"
    return f"{a.kind.replace('_', ' ')}{f' rope {a.rope + 1}' if a.rope is not None else ''} until {until} ({a.note})"


def hoist_line(st: Any) -> str:
    """The hoist's standing status (`alarms.HoistStatus`) short enough for the terminal: the
    imbalance the seals can hide at the current rope tension against the limit, then what the
    station cannot watch on this node; else the status's own text."""
    hidden, rope_n, limit = (getattr(st, k, None) for k in ("hidden_frac", "rope_n", "limit"))
    notes = list(getattr(st, "notes", ()) or ())
    if hidden is None or rope_n is None:
        return getattr(st, "text", "") or ""
    line = f"seals can hide {hidden * 100:.1f} % at {rope_n / 1000:.1f} kN/rope"
    if limit:
        line += f", {'beyond' if hidden >= limit else 'within'} the {limit * 100:.0f} % limit"
    return "; ".join([line] + notes)


# -- the command -------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", action="append", required=True, metavar="URL",
                   help="receiver serial port (device path or pyserial URL); give twice for two receivers; "
                        "NAME=URL names the receiver")
    p.add_argument("--db", help="SQLite log to append frames and alarm events to")
    p.add_argument("--config", action="append", default=[], metavar="NODE.JSON",
                   help="node.json: cylinder areas, rated tension, alarm thresholds and the node key "
                        "(repeatable, one per node of the same hoist; merged with --key-file)")
    add_key_arguments(p)
    p.add_argument("--accept-rewound", action="append", type=node_id, default=[], metavar="NODE",
                   help="operator decision: NODE's boot counter really went back (flash wiped or replaced); "
                        "take its next authenticated frame as its new baseline (repeatable; logged)")
    p.add_argument("--baud", type=int, default=DEFAULT_BAUDRATE,
                   help=f"baud rate of the receiver lines (default {DEFAULT_BAUDRATE})")
    p.add_argument("--rs485", action="store_true",
                   help="half-duplex RS485 mode for adapters whose driver needs it (RTS switching)")
    p.add_argument("--refresh-hz", type=float, default=4.0, help="screen refreshes (station ticks) per second")
    p.add_argument("--headless", action="store_true",
                   help="no screen: run as a service and print every alarm event as one JSON line on stdout "
                        "(stops on SIGTERM or SIGINT)")
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


def handle_keys(pipeline: HoistPipeline, view: MonitorView, k: str, operator: str) -> bool:
    """Act on key presses; False when the operator quits. `a` and `y` become the station's
    commands (carried out at its next pump); `r` asks to accept the first refused node,
    `y` confirms it, any other key cancels the question; `s` and `u` ask which alarm to
    shelve or unshelve (`ask`)."""
    k = k.lower()
    if view.question is not None:
        ask(pipeline, view, k[:1], operator)
        return True
    if "q" in k:
        return False
    if view.confirm_accept is not None:
        node, view.confirm_accept = view.confirm_accept, None
        if "y" in k:
            pipeline.submit(AcceptRewound(operator, "terminal", node=node))
        return True
    if "a" in k:
        pipeline.submit(Acknowledge(operator, "terminal"))
    if "n" in k:
        view.next_node()
    if "r" in k and view.refused:
        view.confirm_accept = min(view.refused)
    if "s" in k and view.alarms:
        view.question = Question("shelve", view.alarms[:SHOWN_ALARMS])
    elif "u" in k and view.shelved:
        view.question = Question("unshelve", view.shelved[:9])
    return True


def ask(pipeline: HoistPipeline, view: MonitorView, key: str, operator: str) -> None:
    """One step of the shelve or unshelve question: a digit among those offered moves it on
    (the last becomes the station's command), any other key cancels it."""
    q = view.question
    assert q is not None
    offered = {"which": len(q.choices), "minutes": len(SHELVE_MINUTES), "reason": len(SHELVE_REASONS)}[q.step]
    if not (key.isdigit() and 1 <= int(key) <= offered):
        view.question = None
        return
    i = int(key) - 1
    if q.step == "which" and q.action == "unshelve":
        pipeline.submit(Unshelve(operator, "terminal", alarm=q.choices[i].id))
        view.question = None
    elif q.step == "which":
        q.alarm, q.step = q.choices[i].id, "minutes"
    elif q.step == "minutes":
        q.minutes, q.step = SHELVE_MINUTES[i], "reason"
    else:
        pipeline.submit(Shelve(operator, "terminal", alarm=q.alarm, minutes=q.minutes, reason=SHELVE_REASONS[i]))
        view.question = None


def live_loop(pipeline: HoistPipeline, view: MonitorView, console: Console, refresh_hz: float,
              done: Callable[[], bool] = lambda: False, pipelines: Sequence[HoistPipeline] | None = None) -> None:
    """Run the pipeline (or `pipelines`, all pumped and ticked; keys act on `pipeline`) and draw
    the view until `q` or `done()`, on `assembly.run_loop`: a tick and a new screen each
    1/refresh_hz s and at once after a key; `a` acknowledges, `r` `y` accepts a refused node;
    bell on new alarms."""
    from rich.live import Live

    keys = KeyReader()
    operator = operator_name()
    last_bell = 0.0
    quit_ = False

    def read_keys(timeout_s: float) -> bool:
        nonlocal quit_
        k = keys.read(timeout_s)
        if k and not handle_keys(pipeline, view, k, operator):
            quit_ = True
        return bool(k)

    try:
        with Live(view.render(pipeline.clock()), console=console, screen=console.is_terminal,
                  auto_refresh=False, transient=False) as live:
            def draw() -> None:
                nonlocal last_bell
                now = pipeline.clock()
                unacked = any(not acked for _, acked in view.alarm_rows)
                ring = view.new_raises > 0 or (unacked and now - last_bell > BELL_REPEAT_S)
                view.new_raises = 0
                live.update(view.render(now), refresh=True)
                if ring and (unacked or last_bell == 0.0):
                    console.bell()
                    last_bell = now

            period = 1.0 / refresh_hz
            run_loop(pipelines or [pipeline], period, lambda: quit_ or done(), wait=read_keys, on_tick=draw,
                     first_tick_s=period)
    finally:
        keys.close()


class JsonAlarmLines(Listener):
    """Every alarm event as one JSON line (the headless station's output, docs/operator.md)."""

    name = "json lines"

    def __init__(self, out: IO[str]) -> None:
        self.out = out

    def on_event(self, e: AlarmEvent) -> None:
        t = datetime.datetime.fromtimestamp(e.time_s, datetime.timezone.utc)
        value, threshold = e.columns()     # a station event's numbers as the log has them
        line = {"event": e.action, "alarm": e.kind, "id": e.alarm, "node": e.node,
                "rope": None if e.rope is None else e.rope + 1, "value": value, "worst": e.worst,
                "threshold": threshold, "t": t.isoformat(timespec="milliseconds").replace("+00:00", "Z"),
                "operator": e.operator, "annunciated": e.annunciated, "message": e.message}
        self.out.write(json.dumps(line, allow_nan=False, default=str) + "\n")
        self.out.flush()


def spec_from_args(args: argparse.Namespace) -> HoistSpec:
    """The one hoist `ropemon monitor` watches, from its command line. ValueError says why not."""
    keys = keys_from_options(args.key_file, args.config, args.accept_rewound)
    figures = figures_from_configs(args.config)
    # The nodes it has keys for are the nodes it must hear: silent until heard.
    settings = dataclasses.replace(alarm_settings(figures, args.silent_s), nodes=tuple(sorted(keys or ())))
    return HoistSpec("monitor", figures, keys, settings, receivers=tuple(receiver_names(args.port)), baud=args.baud,
                     rs485=args.rs485, accept_rewound=tuple(args.accept_rewound))


def run(args: argparse.Namespace) -> int:
    try:
        spec = spec_from_args(args)
    except ValueError as e:
        print(f"ropemon monitor: {e}", file=sys.stderr)
        return 2
    store = None
    if args.db:
        from ropemon.station import files
        from ropemon.station.store import Store, StoreError
        try:
            files.check_sqlite(args.db, "database", StoreError, new_ok=True)  # not a FIFO, not another file
            store = Store(args.db)
        except StoreError as e:
            print(f"ropemon monitor: {e}", file=sys.stderr)
            return 2
    view: Listener = JsonAlarmLines(sys.stdout) if args.headless else MonitorView(spec.figures)
    # Wall-clock time, like frames.rx_time: alarm raise/clear/ack times in the log must be
    # readable as times of day (a hoist-room PC slews its clock with NTP, it does not jump).
    hoist = assembly.build_hoist(spec, time.time, store=store, views=[view])
    pipeline = hoist.pipeline
    resumed = pipeline.resumed_text()
    if resumed is not None:
        print(f"ropemon monitor: {resumed}", file=sys.stderr)
    operator = operator_name()
    for node in args.accept_rewound:
        pipeline.submit(AcceptRewound(operator, "command line", node=node, how="with --accept-rewound"))
    try:
        hoist.start()
        if isinstance(view, MonitorView):
            live_loop(pipeline, view, Console(), args.refresh_hz)
        else:     # no screen: until SIGTERM or SIGINT
            stop = threading.Event()
            for sig in (signal.SIGTERM, signal.SIGINT):
                signal.signal(sig, lambda *_: stop.set())
            run_loop([pipeline], 1.0 / args.refresh_hz, stop.is_set, wait=stop.wait)
    finally:
        pipeline.close()
        if store is not None:
            store.close()
    return 0
