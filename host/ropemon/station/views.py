"""What the faces say in words: the figures and lines the terminal monitor and the web page
both show of a frame, the link and an alarm (ropes numbered from 1, as on the cage)."""
from __future__ import annotations

from typing import Any

from ropemon.station.alarms import WARNING_KINDS, ActiveAlarm
from ropemon.station.equalizer import has_positions as layout_has_positions
from ropemon.station.protocol import DAN_TO_N, Frame, L

POS_ABSENT = L.POS_ABSENT   # no healthy displacement sample in the window
STALE_S = 2.0               # a node's last frame older than this: its figures are greyed as not current


def piston(frame: Frame, rope: int) -> tuple[float | None, bool, bool]:
    """(position in m or None, the displacement channel faulted, the node saw the piston within
    the stroke margin of an end during the window) of one rope (from 0) of a frame."""
    pos = frame.ropes[rope].pos_01mm if rope < len(frame.ropes) else POS_ABSENT
    fault = bool(frame.fault_mask >> (L.FAULT_DISPLACEMENT_SHIFT + rope) & 1)
    mask = frame.stroke_mask
    near = bool(mask >> (L.STROKE_LOW_SHIFT + rope) & 1 or mask >> (L.STROKE_HIGH_SHIFT + rope) & 1)
    return (None if pos == POS_ABSENT else pos / 10_000), fault, near


def has_positions(frame: Frame) -> bool:
    """The frame carries ropes and its layout their piston positions (version 3 on)."""
    return layout_has_positions(frame) and bool(frame.ropes)


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
    """An alarm row of a warning (shown in yellow, after the alarms): a kind of
    `alarms.WARNING_KINDS` (DEVIATION POSSIBLE, the rope-adjustment advisory)."""
    return any(text.startswith(k.upper().replace("_", " ")) for k in WARNING_KINDS)


def alarm_text(a: ActiveAlarm) -> str:
    """One line for the operator; ropes numbered from 1 as on the cage. A cleared alarm shows the
    worst value it reached, not the value it cleared at."""
    rope = f" rope {a.rope + 1}" if a.rope is not None else ""
    v = a.value if a.present or a.worst is None else a.worst
    thr = a.threshold
    reached = "" if a.present else "reached "
    if a.kind == "deviation" and v is not None and thr is not None:
        what = f"{reached}{v * 100:+.1f} % from mean (limit {thr * 100:.0f} %)"
        if a.present and a.worst is not None and abs(a.worst) > abs(v) + 0.0005:
            what += f", worst {a.worst * 100:+.1f} %"
    elif a.kind == "deviation_possible" and v is not None and thr is not None and a.band is not None:
        what = f"{v * 100:+.1f} % +-{a.band * 100:.1f} from mean: may reach {thr * 100:.0f} %"
    elif a.kind == "overload" and v is not None and thr is not None:
        what = f"{reached}total {v * DAN_TO_N / 1000:.1f} kN > {thr * DAN_TO_N / 1000:.1f} kN"
    elif a.kind == "slack" and v is not None and thr is not None:
        what = f"{reached}{v * DAN_TO_N / 1000:.1f} kN < {thr * DAN_TO_N / 1000:.1f} kN"
    elif a.kind == "battery_low" and v is not None:
        what = f"{reached}{v / 1000:.2f} V"
    elif a.kind == "silent" and v is not None:
        what = f"no frame for {v:.1f} s"
    else:
        what = a.message
    state = "" if a.present else " (cleared, not acknowledged)"
    return f"{a.kind.upper().replace('_', ' ')}{rope}: {what}{state}"


#: Why a rope's reading is marked held back (`Frame.held_back`), where a view explains it.
HELD_BACK_WHY = ("compensation held back at rest: the piston's own travel does not support the seal "
                 "friction the model holds, so the reading is nearer p A (the band still covers it)")

