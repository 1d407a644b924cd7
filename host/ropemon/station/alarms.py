"""Operator alarms from decoded frames: thresholds, minimum durations, hysteresis, latching.

Every alarm is one `_Alarm` identified by an id such as "deviation:n1:r2" (kind,
node, rope). Its condition is debounced: it raises only after the raise
condition has held for `raise_after_s` over at least `min_frames` consecutive
evaluations, and clears only after the clear condition (threshold minus
hysteresis) has held for `clear_after_s` likewise; so one noisy frame neither
raises nor clears. A raised alarm latches until acknowledged. Every raise, clear
and acknowledgement is returned as an `AlarmEvent` (`ropemon.station.events`) with time and values (the
caller logs them, e.g. `Store.add_event`).

Kinds: deviation (a rope vs the mean of the ropes), deviation_possible (only with
`AlarmSettings.legacy_deviation_possible`, the station before it watched the equalizer: a
warning that the band of the deviation reaches the limit while the node's deviation does not;
the seals' static friction makes that stand on every rope: the imbalance the seals can hide is
the hoist's standing status instead, `AlarmEngine.hoist_status`), overload (total vs rated),
slack (a rope below a floor), sensor_fault (fault bits), sensor_stuck (a rope's
pressure frozen while the others move, see `StuckTracker`), config_fault, silent
(no frame from a node: also a configured node never heard since the station started),
no_data (no frame from any node since the station started, no node configured),
battery_low, pressure_noise (the node's noise_changed bit: its transmitters' noise moved
beyond what it follows without a re-check), node_imbalance (the node's own imbalance bit),
link_integrity (MAC failures or replays), receiver_down (a receiver's port not open),
station_fault (a part of the station failing, e.g. the log cannot be written); and from the
piston positions of layout version 3 (`ropemon.station.equalizer`, with `AlarmSettings.equalizer`):
stroke_limit (a piston within the stroke margin of an end), not_equalizing (a rope cut off from the
manifold: its tap pressure departs from the others' over a load change; a lagging piston alone,
a seized seal or blocked hose, only with `EqualizerSettings.position_lag`),
oil_loss (the trapped oil's balance drifting) and rope_adjust (an advisory: the pistons' rest
positions trend towards an end from wind to wind).

Fail-safe: the station raises an alarm whenever it cannot vouch for the ropes (no frame,
a receiver down, a station part failing); it is never quiet because it sees nothing.

Lifecycle (after ISA-18.2 / IEC 62682): an alarm raised is unacknowledged; acknowledged
while its condition stays; cleared before it was acknowledged it is "returned to normal,
unacknowledged" and stays listed until acknowledged. An operator may shelve an alarm
(with a reason, until an expiry) or an engineer take it out of service (with a reason,
until returned): it is then not annunciated (listed apart, no acknowledgement needed) but
still evaluated and logged. A rope's deviation and slack alarms are suppressed by design
while that rope's sensor has failed, its stroke_limit and not_equalizing while its
displacement channel has (SENSOR FAULT names it). Each alarm keeps its worst
value since it was raised, its raise, clear and acknowledgement times and who acknowledged.
More than FLOOD_RAISES raises within FLOOD_S is an alarm flood (ALARM FLOOD).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from ropemon.station.alarmstate import Debounce, Timing, _Alarm, _worse
from ropemon.station.equalizer import (AdjustForecast, EqualizerSettings, EqualizingTracker, OilTracker,
                                       RestTracker, has_positions, positions, stroke_check)
from ropemon.station.events import AlarmEvent
from ropemon.station.protocol import DAN_TO_N, L, Frame
from ropemon.station.stuck import StuckTracker
from ropemon.station.uncertainty import (BandParams, DeviationBand, RopeInterval, SealBandTracker, deviation_bounds,
                                         hidden_reach)

#: Alarm flood: more than this many raises within FLOOD_S (ISA-18.2's 10 per 10 minutes).
FLOOD_RAISES, FLOOD_S = 10, 600.0
#: Priority of each kind (1 highest); kinds not listed are 1.
PRIORITY = {"stroke_limit": 1, "not_equalizing": 1,
            "battery_low": 2, "pressure_noise": 2, "sensor_stuck": 2, "alarm_flood": 2, "oil_loss": 2,
            "deviation_possible": 3, "rope_adjust": 3}
#: Kinds judged on a rope's piston position: not judged while its displacement channel fails.
POSITION_KINDS = ("stroke_limit", "not_equalizing")
#: Kinds judged on a rope's tension: not judged while the rope has none (its sensor failed).
TENSION_KINDS = ("deviation", "deviation_possible", "slack")
SENSOR_FAULT_BITS = L.ST_PRESSURE_FAULT | L.ST_DISPLACEMENT_FAULT | L.ST_SPEED_FAULT


@dataclass(frozen=True)
class AlarmSettings:
    """Thresholds; a threshold of None disables that alarm."""

    deviation_frac: float = 0.10            # the regulation: +-10 % of the mean tension
    deviation_hysteresis_frac: float = 0.02
    deviation_min_mean_dan: int = 100       # below this mean the ropes are unloaded: no check
    rated_load_dan: int | None = None       # rated total static load (sum of rope tensions)
    overload_frac: float = 1.0              # raise above rated_load_dan * overload_frac
    overload_hysteresis_frac: float = 0.05
    slack_dan: int | None = None            # a rope below this is slack
    slack_hysteresis_dan: int = 50
    battery_low_mv: int | None = None       # besides the node's own battery_low status bit
    battery_hysteresis_mv: int = 100
    silent_s: float = 5.0                   # no frame from a node for longer than this
    # sensor_stuck: a rope's raw_kpa stays within +-stuck_deadband_kpa for stuck_s while the mean
    # of the other ropes' raw_kpa moves by more than stuck_others_kpa (see StuckTracker).
    stuck_s: float | None = 5.0
    stuck_deadband_kpa: int = 5
    stuck_others_kpa: int = 50
    stuck_moving_s: float = 1.0             # clear: the rope moved within this, held clear_after_s
    timing: Timing = Timing()
    fault_timing: Timing = Timing(raise_after_s=0.0, clear_after_s=2.0, min_frames=2)
    silent_timing: Timing = Timing(raise_after_s=0.0, clear_after_s=1.0, min_frames=1)
    link_timing: Timing = Timing(raise_after_s=0.0, clear_after_s=10.0, min_frames=1)
    receiver_down_s: float = 2.0            # a receiver's port not open for longer than this
    receiver_timing: Timing = Timing(raise_after_s=0.0, clear_after_s=2.0, min_frames=1)
    nodes: tuple[int, ...] = ()             # the nodes the station is configured for: silent until heard
    # the seal's friction lines and the band's parameters (ropemon.station.uncertainty): with them the
    # engine keeps a band per rope (`deviation_bands`) and the hoist's standing status (`hoist_status`);
    # None: no band
    band: BandParams | None = None
    # the station before it watched the equalizer (the evaluation's baseline): deviation_possible
    # raised whenever the band reaches the limit (with the seals' friction: on every rope, always)
    legacy_deviation_possible: bool = False
    # NODE IMBALANCE on the node's own imbalance bit: the same window means and limit as
    # DEVIATION without its minimum duration, hysteresis or rope, so a duplicate of it (ISA-18.2);
    # off, the bit shows in the node's flags. The evaluation's legacy station has it on.
    node_imbalance: bool = False
    # the equalizer's alarms from the piston positions (ropemon.station.equalizer); None: none
    equalizer: EqualizerSettings | None = EqualizerSettings()

    @classmethod
    def from_loads(cls, rated_load_dan: int, empty_load_dan: int, n_ropes: int,
                   slack_frac_of_empty: float = 0.6, **kw) -> "AlarmSettings":
        """Overload at the rated total load; a rope is slack below `slack_frac_of_empty` of its
        share of the empty conveyance load (the Quebec S-2.1 r.14 s.253.2 rule: 60 %)."""
        if n_ropes < 1 or empty_load_dan <= 0 or rated_load_dan <= 0:
            raise ValueError("rated_load_dan, empty_load_dan and n_ropes must be positive")
        slack = round(slack_frac_of_empty * empty_load_dan / n_ropes)
        return cls(rated_load_dan=rated_load_dan, slack_dan=slack, **kw)


@dataclass(frozen=True)
class ActiveAlarm:
    """What a display shows: present = condition now, latched = awaiting acknowledgement;
    `state` names the lifecycle state (module docstring)."""

    id: str
    kind: str
    node: int | None
    rope: int | None
    present: bool
    latched: bool
    value: float | None
    threshold: float | None
    message: str
    raised_s: float | None
    band: float | None = None    # deviation_possible: how far beyond |value| the deviation may reach
    worst: float | None = None
    state: str = "unacknowledged"   # unacknowledged, acknowledged, rtn_unacknowledged, shelved, ...
    priority: int = 1               # 1 highest
    cleared_s: float | None = None
    acked_s: float | None = None
    acked_by: str | None = None
    shelved_until: float | None = None
    note: str | None = None         # shelved or out of service: the reason and who

    @property
    def warning(self) -> bool:
        """A warning or advisory (lower priority than the alarms): deviation_possible, rope_adjust."""
        return self.kind in WARNING_KINDS


WARNING_KINDS = frozenset({"deviation_possible", "rope_adjust"})


@dataclass(frozen=True)
class HoistStatus:
    """A node's hoist as it stands (not an alarm: nothing the operator does clears it).

    `hidden_frac`: the imbalance (fraction of the mean) the seals' static friction can hide at
    the current mean rope tension (`uncertainty.hidden_reach`; None: no band, or the ropes
    unloaded); `text`: one line for an operator; `notes`: what the station cannot watch on this
    node (no piston positions, no oil balance); `forecast`: per rope the rest positions' trend
    (`equalizer.adjust_forecast`, empty before enough winds)."""

    node: int
    hidden_frac: float | None
    rope_n: float | None
    limit: float | None
    positions: bool | None            # the node sends piston positions (layout version 3)
    text: str
    notes: tuple[str, ...] = ()
    forecast: tuple[AdjustForecast | None, ...] = ()
    oil_balance_m3: float | None = None   # oil lost since the station started watching (+: lost)


def _fault_ropes(mask: int) -> str:
    """What a fault_mask names, ropes from 1 as on the cage (layout: bit i pressure loop of rope
    i+1, bit FAULT_DISPLACEMENT_SHIFT + i its displacement channel)."""
    parts = []
    for shift, what in ((L.FAULT_PRESSURE_SHIFT, "pressure loop"), (L.FAULT_DISPLACEMENT_SHIFT, "displacement")):
        ropes = [str(i + 1) for i in range(4) if mask >> (shift + i) & 1]
        if ropes:
            parts.append(f"{what} of rope{'s' if len(ropes) > 1 else ''} {', '.join(ropes)}")
    return (": " + "; ".join(parts)) if parts else ""


class AlarmEngine:
    def __init__(self, settings: AlarmSettings | None = None):
        self.settings = settings or AlarmSettings()
        self._alarms: dict[str, _Alarm] = {}
        self._stuck: dict[int, StuckTracker] = {}
        self._bands: dict[int, SealBandTracker] = {}
        self._last_frame_s: dict[int, float] = {}
        self._link_bad: dict[str, int] = {}
        self._started_s: float | None = None      # the first update or tick: when the station began to look
        self._down_since: dict[str, float] = {}   # receiver -> when its port was first seen down
        self._raises: deque[float] = deque()       # times of annunciated raises (the flood count)
        self._equalizing: dict[int, EqualizingTracker] = {}
        self._equalizing_ids: dict[int, tuple[str, ...]] = {}   # per node: its ropes' not_equalizing ids
        self._oil: dict[int, OilTracker] = {}
        self._rests: dict[int, RestTracker] = {}
        self._forecast: dict[int, list[AdjustForecast | None]] = {}
        self._layout: dict[int, int] = {}            # node -> layout version of its last frame
        self._mean_rope_n: dict[int, float | None] = {}
        self._per_rope: dict[int, list[_Alarm]] = {}   # node -> its per-rope alarms that can be suppressed
        self._eq_timing: tuple | None = None
        self.events: deque[AlarmEvent] = deque(maxlen=10000)  # recent history; the store keeps all

    # -- inputs ---------------------------------------------------------------

    def update(self, frame: Frame, now_s: float) -> list[AlarmEvent]:
        """Evaluate every frame-based alarm of frame.node at host time now_s."""
        s = self.settings
        ev: list[AlarmEvent] = []
        node = frame.node
        if self._started_s is None:
            self._started_s = now_s
        self._last_frame_s[node] = now_s
        self._check_arrived(ev, node, now_s)
        ropes = frame.ropes
        # Ropes whose sensor gave no healthy sample carry TENSION_ABSENT: they are not judged
        # (their alarms hold their state; sensor_fault reports them) and not averaged in.
        present = [(i, r.mean_dan) for i, r in enumerate(ropes) if r.mean_dan != L.TENSION_ABSENT]
        judged = {i for i, _ in present}
        for a in self._per_rope.get(node, ()):
            if a.kind in TENSION_KINDS and a.rope < len(ropes):
                self._suppress(a, a.rope not in judged)
        if ropes:
            self._mean_rope_n[node] = (sum(t for _, t in present) / len(present) * DAN_TO_N) if present else None
        if s.band is not None and s.deviation_frac is not None and ropes:
            tr = self._bands.get(node)
            if tr is None:
                tr = self._bands[node] = SealBandTracker(s.band)
            tr.update(frame)
        if present:
            self._check_tension(ev, node, len(ropes), present, now_s)
        if s.stuck_s is not None:
            self._check_stuck(ev, node, ropes, now_s, s.stuck_s)
        if s.equalizer is not None and ropes:
            self._check_equalizer(ev, frame, now_s, s.equalizer)
        self._check_node_status(ev, frame, now_s)
        return self._log(ev)

    def _check_arrived(self, ev, node: int, now_s: float) -> None:
        """A frame from `node`: no_data and its silent alarm clear."""
        s = self.settings
        self._step(ev, "no_data", "no_data", timing=s.silent_timing, now_s=now_s, raise_cond=False,
                   clear_cond=True, value=0.0, threshold=s.silent_s, message="frames arriving")
        self._step(ev, f"silent:n{node}", "silent", node=node, timing=s.silent_timing, now_s=now_s,
                   raise_cond=False, clear_cond=True, value=0.0, threshold=s.silent_s, message="frames arriving")

    def _check_tension(self, ev, node: int, n_ropes: int, present: list[tuple[int, int]], now_s: float) -> None:
        """deviation, deviation_possible (legacy), overload and slack from the tensions of the ropes
        `present` (rope, mean_dan); an absent rope is taken at the mean for the total."""
        s = self.settings
        tensions = [t for _, t in present]
        mean = sum(tensions) / len(tensions)
        # Connected cylinders equalise the ropes, so an absent rope is taken at the mean.
        total = round(mean * n_ropes)
        estimated = len(present) < n_ropes
        if s.deviation_frac is not None and len(present) >= 2:
            thr = s.deviation_frac
            for i, t in present:
                dev = (t - mean) / mean if mean >= s.deviation_min_mean_dan else 0.0
                a = abs(dev)
                self._step(ev, f"deviation:n{node}:r{i}", "deviation", node=node, rope=i, timing=s.timing,
                           now_s=now_s, raise_cond=a > thr, clear_cond=a < thr - s.deviation_hysteresis_frac,
                           value=round(dev, 4), threshold=thr,
                           message=f"rope {i + 1} {t} daN is {dev:+.1%} from the mean {mean:.0f} daN")
        if s.band is not None and s.deviation_frac is not None and s.legacy_deviation_possible:
            # after the deviation alarms: the warning yields to a raised certain alarm
            self._check_possible(ev, node, self._bands[node].last, now_s, None)
        if s.rated_load_dan is not None:
            limit = s.rated_load_dan * s.overload_frac
            low = s.rated_load_dan * (s.overload_frac - s.overload_hysteresis_frac)
            self._step(ev, f"overload:n{node}", "overload", node=node, timing=s.timing, now_s=now_s,
                       raise_cond=total > limit, clear_cond=total < low, value=total, threshold=limit,
                       message=f"total load {total} daN{' (estimated: a rope absent)' if estimated else ''} "
                       f"vs limit {limit:.0f} daN")
        if s.slack_dan is not None:
            for i, t in present:
                self._step(ev, f"slack:n{node}:r{i}", "slack", node=node, rope=i, timing=s.timing, now_s=now_s,
                           raise_cond=t < s.slack_dan, clear_cond=t > s.slack_dan + s.slack_hysteresis_dan,
                           value=t, threshold=s.slack_dan,
                           message=f"rope {i + 1} {t} daN below slack floor {s.slack_dan} daN")

    def _check_node_status(self, ev, frame: Frame, now_s: float) -> None:
        """What the node says of itself: sensor_fault, config_fault, battery_low, node_imbalance,
        pressure_noise (its status bits, fault mask and battery)."""
        s = self.settings
        node = frame.node
        fault = bool(frame.status & SENSOR_FAULT_BITS) or frame.fault_mask != 0
        flags = ",".join(f for f in frame.status_flags if f.endswith("_fault") and f != "config_fault")
        self._step(ev, f"sensor_fault:n{node}", "sensor_fault", node=node, timing=s.fault_timing, now_s=now_s,
                   raise_cond=fault, clear_cond=not fault, value=frame.fault_mask,
                   message=f"sensor fault {flags or '-'}{_fault_ropes(frame.fault_mask)}")
        cfg = bool(frame.status & L.ST_CONFIG_FAULT) or frame.kind == L.KIND_STATUS
        self._step(ev, f"config_fault:n{node}", "config_fault", node=node, timing=s.fault_timing, now_s=now_s,
                   raise_cond=cfg, clear_cond=not cfg, message="node reports a config fault: no compensated tension")
        bit = bool(frame.status & L.ST_BATTERY_LOW)
        mv = frame.battery_mv
        if s.battery_low_mv is not None:
            lo = bit or mv < s.battery_low_mv
            hi = not bit and mv > s.battery_low_mv + s.battery_hysteresis_mv
        else:
            lo, hi = bit, not bit
        self._step(ev, f"battery_low:n{node}", "battery_low", node=node, timing=s.timing, now_s=now_s,
                   raise_cond=lo, clear_cond=hi, value=mv, threshold=s.battery_low_mv, message=f"battery {mv} mV low")
        imb = bool(frame.status & L.ST_IMBALANCE) and s.node_imbalance
        self._step(ev, f"node_imbalance:n{node}", "node_imbalance", node=node, timing=s.fault_timing, now_s=now_s,
                   raise_cond=imb, clear_cond=not imb,
                   message="the node reports a rope beyond its own imbalance limit")
        noisy = bool(frame.status & L.ST_NOISE_CHANGED)
        self._step(ev, f"pressure_noise:n{node}", "pressure_noise", node=node, timing=s.fault_timing, now_s=now_s,
                   raise_cond=noisy, clear_cond=not noisy,
                   message=f"pressure transmitters' noise more than {L.NOISE_TOL_Q10 * 100 // 1024} % off the "
                   "commissioned: re-check the config (ropemon fit-compliance --check)")

    def tick(self, now_s: float) -> list[AlarmEvent]:
        """Time passes without frames: the node-silent alarm (for a configured node never heard,
        counted from the station's start), and no_data while no node has been heard at all."""
        s = self.settings
        ev: list[AlarmEvent] = []
        for a in list(self._alarms.values()):
            if a.shelved_until is not None and now_s >= a.shelved_until:
                ev += self.unshelve(a.id, now_s)
        while self._raises and self._raises[0] < now_s - FLOOD_S:
            self._raises.popleft()
        n = len(self._raises)
        self._step(ev, "alarm_flood", "alarm_flood", timing=s.silent_timing, now_s=now_s, raise_cond=n > FLOOD_RAISES,
                   clear_cond=n <= FLOOD_RAISES // 2, value=n, threshold=FLOOD_RAISES,
                   message=f"alarm flood: {n} alarms raised in the last {FLOOD_S / 60:.0f} min")
        if self._started_s is None:
            self._started_s = now_s
        quiet_since_start = now_s - self._started_s
        if not self._last_frame_s and not s.nodes:
            self._step(ev, "no_data", "no_data", timing=s.silent_timing, now_s=now_s,
                       raise_cond=quiet_since_start > s.silent_s, clear_cond=False,
                       value=round(quiet_since_start, 3), threshold=s.silent_s,
                       message=f"no frame from any node since the station started {quiet_since_start:.0f} s ago")
        for node in s.nodes:
            if node not in self._last_frame_s:
                self._step(ev, f"silent:n{node}", "silent", node=node, timing=s.silent_timing, now_s=now_s,
                           raise_cond=quiet_since_start > s.silent_s, clear_cond=False,
                           value=round(quiet_since_start, 3), threshold=s.silent_s,
                           message=f"no frame from node {node} since the station started {quiet_since_start:.0f} s ago")
        for node, last in self._last_frame_s.items():
            quiet = now_s - last
            self._step(ev, f"silent:n{node}", "silent", node=node, timing=s.silent_timing, now_s=now_s,
                       raise_cond=quiet > s.silent_s, clear_cond=quiet <= s.silent_s, value=round(quiet, 3),
                       threshold=s.silent_s, message=f"no frame from node {node} for {quiet:.1f} s")
            if node in self._bands and quiet > 0 and s.legacy_deviation_possible:
                self._check_possible(ev, node, self._bands[node].intervals(quiet), now_s, quiet)
        return self._log(ev)

    def update_link(self, source: str, mac_fail: int, replayed: int, now_s: float,
                    restarts: int = 0) -> list[AlarmEvent]:
        """Decoder counts of one receiver (cumulative): any increase raises link_integrity.

        `restarts` (seq restarts accepted after a node reset) count too: the anti-replay
        window cannot tell a reset from a replayed boot, so the operator is told.
        """
        bad = mac_fail + replayed + restarts
        new = bad - self._link_bad.get(source, 0)
        self._link_bad[source] = bad
        ev: list[AlarmEvent] = []
        self._step(ev, f"link_integrity:{source}", "link_integrity", timing=self.settings.link_timing,
                   now_s=now_s, raise_cond=new > 0, clear_cond=new <= 0, value=new, threshold=0,
                   message=f"receiver {source}: {mac_fail} MAC failures, {replayed} replays, "
                   f"{restarts} node seq restarts in total")
        return self._log(ev)

    def update_receiver(self, name: str, url: str | None, connected: bool, why: str | None,
                        now_s: float) -> list[AlarmEvent]:
        """A receiver's port state (each tick): receiver_down after `receiver_down_s` not open."""
        s = self.settings
        if connected:
            self._down_since.pop(name, None)
        else:
            self._down_since.setdefault(name, now_s)
        down_s = now_s - self._down_since.get(name, now_s)
        ev: list[AlarmEvent] = []
        self._step(ev, f"receiver_down:{name}", "receiver_down", timing=s.receiver_timing, now_s=now_s,
                   raise_cond=not connected and down_s > s.receiver_down_s, clear_cond=connected,
                   value=round(down_s, 1), threshold=s.receiver_down_s,
                   message=f"receiver {name} ({url}) down for {down_s:.0f} s: {why or 'not open'}")
        return self._log(ev)

    def update_fault(self, source: str, active: bool, message: str, now_s: float) -> list[AlarmEvent]:
        """A part of the station failing (`source`, e.g. the log) or working again."""
        ev: list[AlarmEvent] = []
        self._step(ev, f"station_fault:{source}", "station_fault", timing=self.settings.receiver_timing,
                   now_s=now_s, raise_cond=active, clear_cond=not active, message=message)
        return self._log(ev)

    def ack(self, name_or_id: str, now_s: float, by: str | None = None) -> list[AlarmEvent]:
        """Acknowledge latched alarms by id, by kind, or all with "*"; `by` (who) is recorded."""
        ev = []
        for a in self._alarms.values():
            if a.latched and name_or_id in ("*", a.id, a.kind):
                a.latched = False
                a.acked_s, a.acked_by = now_s, by
                ev.append(self._event(a, now_s, "ack", f"acknowledged by {by}: {a.message}" if by else None, by))
        return self._log(ev)

    def nodes(self) -> list[int]:
        """The nodes frames have come from."""
        return sorted(self._last_frame_s)

    # -- outputs --------------------------------------------------------------

    def active(self) -> list[ActiveAlarm]:
        """Annunciated alarms present or latched (unacknowledged, acknowledged, returned to
        normal unacknowledged): by priority, then oldest raise first (first out)."""
        out = [self._view(a) for a in self._alarms.values() if a.active and not a.hidden]
        return sorted(out, key=lambda x: (x.priority, x.raised_s or 0.0, x.id))

    def hidden(self) -> list[ActiveAlarm]:
        """Alarms shelved, out of service or suppressed by design (present or not)."""
        return sorted((self._view(a) for a in self._alarms.values() if a.hidden), key=lambda x: x.id)

    @staticmethod
    def _view(a: _Alarm) -> ActiveAlarm:
        return ActiveAlarm(a.id, a.kind, a.node, a.rope, a.present, a.latched, a.value, a.threshold,
                           a.message, a.raised_s, a.band, a.worst, a.state(), PRIORITY.get(a.kind, 1),
                           a.cleared_s, a.acked_s, a.acked_by, a.shelved_until, a.shelved or a.out_of_service)

    # -- operator actions (each logged with who) ----------------------------------

    def shelve(self, alarm_id: str, now_s: float, until_s: float, reason: str, by: str) -> list[AlarmEvent]:
        """Shelve one alarm until `until_s` (then it returns by itself): not annunciated meanwhile.
        Raises KeyError for an alarm the engine does not know, ValueError without a reason or
        with an expiry not in the future."""
        a = self._alarms[alarm_id]
        if not reason.strip() or not until_s > now_s:
            raise ValueError("shelving needs a reason and an expiry in the future")
        a.shelved, a.shelved_until, a.latched = f"{reason} ({by})", until_s, False
        return self._log([self._event(a, now_s, "shelve", f"shelved by {by} until t={until_s:.0f} s: {reason}", by)])

    def unshelve(self, alarm_id: str, now_s: float, by: str | None = None) -> list[AlarmEvent]:
        a = self._alarms[alarm_id]
        if a.shelved is None:
            return []
        a.shelved, a.shelved_until = None, None
        a.latched = a.present           # annunciated again: a present alarm needs an acknowledgement
        why = f"unshelved by {by}" if by else "shelving expired"
        return self._log([self._event(a, now_s, "unshelve", f"{why}: {a.message}", by)])

    def remove_from_service(self, alarm_id: str, now_s: float, reason: str, by: str) -> list[AlarmEvent]:
        """Take an alarm out of service (maintenance) until returned; KeyError, ValueError as `shelve`."""
        a = self._alarms[alarm_id]
        if not reason.strip():
            raise ValueError("taking an alarm out of service needs a reason")
        a.out_of_service, a.latched = f"{reason} ({by})", False
        return self._log([self._event(a, now_s, "out_of_service", f"out of service by {by}: {reason}", by)])

    def return_to_service(self, alarm_id: str, now_s: float, by: str) -> list[AlarmEvent]:
        a = self._alarms[alarm_id]
        if a.out_of_service is None:
            return []
        a.out_of_service = None
        a.latched = a.present
        return self._log([self._event(a, now_s, "in_service", f"returned to service by {by}: {a.message}", by)])

    def known(self) -> list[str]:
        """Every alarm id the engine has seen (what can be shelved or taken out of service)."""
        return sorted(self._alarms)

    def deviation_bands(self, node: int, now_s: float | None = None) -> list[DeviationBand | None]:
        """Per rope of `node`'s last frame: its deviation and band (`ropemon.station.uncertainty`), widened
        for the time since that frame when `now_s` is given; [] without a band."""
        tr = self._bands.get(node)
        if tr is None:
            return []
        age = 0.0 if now_s is None else max(0.0, now_s - self._last_frame_s.get(node, now_s))
        return deviation_bounds(tr.intervals(age))

    def hoist_status(self, node: int) -> HoistStatus | None:
        """`node`'s hoist as it stands (`HoistStatus`): the imbalance the seals can hide at its last
        frame's mean rope tension, and what the station cannot watch there. None without a band
        (no seal friction lines in the config), unless there is something else to say (a node
        sending no piston positions); None for a node never heard."""
        s = self.settings
        if node not in self._last_frame_s:
            return None
        version = self._layout.get(node)
        positions_sent = None if version is None else version >= 3
        notes: list[str] = []
        if positions_sent is False:
            notes.append(f"node {node} sends no piston positions (layout version {version}): end stops, "
                         "equalizing and oil loss not watched")
        q = s.equalizer
        if positions_sent and q is not None and not (q.areas_m2 and any(q.compliance_m_per_pa)):
            notes.append("oil loss not watched: the config has no cylinder areas or hydraulic compliance")
        if positions_sent and q is not None and not q.stroke_m:
            notes.append("stroke unknown: the end stops only from the node's stroke flags, no rope-adjust forecast")
        if s.band is None and positions_sent is not False:
            return None
        limit = s.deviation_frac
        rope_n = self._mean_rope_n.get(node)
        hidden = None
        if s.band is not None and rope_n is not None and rope_n >= s.deviation_min_mean_dan * DAN_TO_N:
            hidden = hidden_reach(s.band, rope_n)
        if hidden is not None:
            within = "" if limit is None else (f" (limit {limit:.0%})" if hidden >= limit else
                                                f" (within the {limit:.0%} limit)")
            text = (f"the seals can hide an imbalance up to {hidden:.1%} at {rope_n / 1e3:.1f} kN per rope{within}: "
                    "check the rope tensions by other means")
        elif s.band is not None:
            text = "ropes unloaded: no imbalance to hide"
        else:
            text = "no seal friction lines in the config: the imbalance the seals can hide is not known"
        if notes and positions_sent is False:
            text += "; " + notes[0]
        oil = self._oil.get(node)
        return HoistStatus(node, hidden, rope_n, limit, positions_sent, text, tuple(notes),
                           tuple(self._forecast.get(node, ())),
                           None if oil is None or oil.last is None else oil.last.balance_m3)

    # -- internals ------------------------------------------------------------

    @staticmethod
    def _suppress(a: _Alarm, suppressed: bool) -> None:
        """A rope's alarm suppressed by design while its sensor is not judged."""
        was, a.suppressed = a.suppressed, suppressed
        if a.suppressed:
            a.latched = False
        elif was:
            a.latched = a.present   # annunciated again: a present alarm needs an ack

    def _check_equalizer(self, ev, frame: Frame, now_s: float, q: EqualizerSettings) -> None:
        """stroke_limit, not_equalizing, oil_loss and rope_adjust from the frame's piston positions
        (`ropemon.station.equalizer`). A frame without positions (layout version 2) judges none:
        `hoist_status` says so."""
        node = frame.node
        self._layout[node] = frame.version
        if not has_positions(frame):
            return
        xs = positions(frame)
        for a in self._per_rope.get(node, ()):
            if a.kind in POSITION_KINDS and a.rope < len(xs):
                self._suppress(a, xs[a.rope] is None)
        timings = self._eq_timing
        if timings is None or timings[0] is not q:
            timings = self._eq_timing = (q, Timing(0.0, q.stroke_clear_s, 1),
                                         Timing(q.equalize_raise_s, q.equalize_clear_s, q.equalize_min_frames),
                                         Timing(q.oil_raise_s, q.oil_clear_s, q.oil_min_frames), Timing(0.0, 0.0, 1))
        strokes = stroke_check(frame, q, xs)
        self._check_stroke(ev, node, strokes, now_s, q, timings[1])
        self._check_equalizing(ev, frame, xs, strokes, now_s, q, timings[2])
        self._check_oil(ev, frame, xs, now_s, q, timings[3])
        self._check_rope_adjust(ev, frame, xs, now_s, q, timings[4])

    def _check_stroke(self, ev, node: int, strokes, now_s: float, q: EqualizerSettings, timing: Timing) -> None:
        """stroke_limit per rope: its piston within the stroke margin of an end (`stroke_check`)."""
        for i, sr in enumerate(strokes):
            if sr is None:
                continue
            aid = f"stroke_limit:n{node}:r{i}"
            if sr.end is None and aid not in self._alarms:
                continue
            stroke = q.per_rope(q.stroke_m, i)
            pos_mm = sr.pos_m * 1e3
            where = (f" (end stop at {'+' if sr.end == 'extended' else '-'}{stroke * 500:.0f} mm, margin "
                     f"{q.margin_m * 1e3:.0f} mm)" if stroke and q.margin_m is not None else " (the node's stroke flag)")
            thr = None
            if stroke and q.margin_m is not None:
                thr = round((stroke / 2 - q.margin_m) * 1e3 * (1 if (sr.end or "extended") == "extended" else -1), 1)
            if sr.end == "extended":
                todo = ("the rope is short against the others, or oil was lost: stop winding people, land the cage, "
                        "adjust the rope (lengthen it) or refill the cylinders")
            elif sr.end == "retracted":
                todo = ("the rope is long against the others (creep, slip), or its cylinder holds too much oil: stop "
                        "winding people, land the cage, adjust the rope (shorten it) or level the cylinders' oil")
            else:
                todo = "out of the margin"
            msg = (f"rope {i + 1} piston at its {sr.end} end: {pos_mm:+.1f} mm from mid-stroke{where}: the "
                   f"equalizer no longer equalizes this rope, its deviation can no longer be ruled out; {todo}"
                   if sr.end else f"rope {i + 1} piston at {pos_mm:+.1f} mm from mid-stroke: {todo}")
            self._step(ev, aid, "stroke_limit", node=node, rope=i, timing=timing, now_s=now_s,
                       raise_cond=sr.end is not None, clear_cond=sr.clear, value=round(pos_mm, 1), threshold=thr,
                       message=msg)

    def _check_equalizing(self, ev, frame: Frame, xs, strokes, now_s: float, q: EqualizerSettings,
                          timing: Timing) -> None:
        """not_equalizing per rope (`EqualizingTracker`); a rope whose piston is at an end is not judged."""
        node = frame.node
        tr = self._equalizing.get(node)
        if tr is None:
            tr = self._equalizing[node] = EqualizingTracker(q)
        skip = [sr is not None and sr.end is not None for sr in strokes]
        alarms = self._alarms
        pts = tr.update(frame, now_s, skip, xs)
        aids = self._equalizing_ids.get(node, ())
        if len(aids) < len(pts):
            aids = self._equalizing_ids[node] = tuple(f"not_equalizing:n{node}:r{i}" for i in range(len(pts)))
        for i, pt in enumerate(pts):
            if pt is None:
                continue
            aid = aids[i]
            if not pt.lags and aid not in alarms:
                continue
            share = None if pt.ratio is None else round(abs(pt.ratio), 3)
            if pt.lags:
                msg = (f"rope {i + 1} not equalizing: {pt.cause}; the equalizer no longer shares its load and its "
                       "deviation can no longer be ruled out: stop winding people at the next landing, check the "
                       "rope's stop valves and hose, and its seal")
            else:
                msg = (f"rope {i + 1} piston moved {pt.own_m * 1e3:+.2f} mm with the others' {pt.others_m * 1e3:+.2f} mm"
                       + (": equalizing again" if pt.follows else ""))
            self._step(ev, aid, "not_equalizing", node=node, rope=i, timing=timing, now_s=now_s,
                       raise_cond=pt.lags, clear_cond=pt.follows, value=share, threshold=q.lag_ratio, message=msg)

    def _check_oil(self, ev, frame: Frame, xs, now_s: float, q: EqualizerSettings, timing: Timing) -> None:
        """oil_loss: the trapped oil's balance drifting beyond what compression and temperature explain."""
        node = frame.node
        oil = self._oil.get(node)
        if oil is None:
            oil = self._oil[node] = OilTracker(q)
        st = oil.update(frame, now_s, xs)
        if st is not None:
            aid = f"oil_loss:n{node}"
            bad = st.lost_m3 > st.band_m3
            if bad or aid in self._alarms:
                self._step(ev, aid, "oil_loss", node=node, timing=timing, now_s=now_s, raise_cond=bad,
                           clear_cond=st.lost_m3 < st.band_m3 / 2, value=round(st.lost_m3 * 1e3, 3),
                           threshold=round(st.band_m3 * 1e3, 3),
                           message=f"oil loss: {st.lost_m3 * 1e3:.2f} L in the last {st.window_s:.0f} s "
                           f"({st.rate_m3_s * 6e4:.2f} L/min), beyond the {st.band_m3 * 1e3:.2f} L the compression and "
                           "temperature explain: the equalizer is losing oil (a leak at a cylinder, hose or the "
                           "connecting assembly); stop winding people at the next landing, find the leak and refill "
                           "before the pistons reach their ends")

    def _check_rope_adjust(self, ev, frame: Frame, xs, now_s: float, q: EqualizerSettings, timing: Timing) -> None:
        """rope_adjust (an advisory) per rope: its piston's rest positions trend towards an end from wind to wind."""
        node = frame.node
        rests = self._rests.get(node)
        if rests is None:
            rests = self._rests[node] = RestTracker(q)
        if rests.update(frame, now_s, xs):
            fc = self._forecast[node] = rests.forecast()
            for i, f in enumerate(fc):
                aid = f"rope_adjust:n{node}:r{i}"
                left = None if f is None else f.winds_left
                due = left is not None and left <= q.adjust_winds
                if not due and aid not in self._alarms:
                    continue
                stroke = q.per_rope(q.stroke_m, i) or 0.0
                limit = (stroke / 2 - (q.margin_m or 0.0)) * 1e3
                msg = (f"rope {i + 1} needs adjusting: its piston's rest position moves {f.trend_m * 1e3:+.2f} mm per "
                       f"wind towards its {f.end} end ({f.last_m * 1e3:+.1f} mm now, margin at "
                       f"{'+' if f.end == 'extended' else '-'}{limit:.0f} mm): {left:.0f} winds left; adjust the rope "
                       "lengths (re-balance the cylinders) at the next maintenance stop"
                       if f is not None and left is not None else f"rope {i + 1}: no trend towards an end")
                self._step(ev, aid, "rope_adjust", node=node, rope=i, timing=timing, now_s=now_s, raise_cond=due,
                           clear_cond=left is None or left > q.adjust_clear_winds,
                           value=None if left is None else round(left, 1), threshold=q.adjust_winds, message=msg)


    def _check_stuck(self, ev, node: int, ropes, now_s: float, stuck_s: float) -> None:
        s = self.settings
        tr = self._stuck.get(node)
        if tr is None:
            tr = self._stuck[node] = StuckTracker(median=s.equalizer is not None)
        raw = [r.raw_kpa for r in ropes]
        present = tuple(k != L.RAW_KPA_ABSENT for k in raw)
        tr.update(raw, present, now_s, s.stuck_deadband_kpa)
        if sum(present) < 2:
            return
        for i, kpa in enumerate(raw):
            if not present[i]:
                continue  # an absent rope holds its alarm state; sensor_fault reports it
            still_s = now_s - tr.anchor_s[i]
            moved = tr.hi_kpa[i] - tr.lo_kpa[i]
            stuck = still_s >= stuck_s and moved > s.stuck_others_kpa
            aid = f"sensor_stuck:n{node}:r{i}"
            if not stuck and aid not in self._alarms:
                continue  # the usual case, as _step would: skip formatting a message per rope and frame
            self._step(ev, aid, "sensor_stuck", node=node, rope=i, timing=s.timing, now_s=now_s, raise_cond=stuck,
                       clear_cond=still_s < s.stuck_moving_s, value=round(still_s, 1), threshold=stuck_s,
                       message=f"rope {i + 1} pressure {kpa} kPa unchanged (+-{s.stuck_deadband_kpa} kPa) for "
                       f"{still_s:.1f} s while the other ropes moved {moved:.0f} kPa: transmitter stuck")

    def _check_possible(self, ev, node: int, iv: list[RopeInterval], now_s: float,
                        quiet_s: float | None) -> None:
        """deviation_possible per rope: the deviation's band reaches the limit (its largest
        |d| over the ropes' intervals, `ropemon.station.uncertainty.deviation_bounds`) while the certain
        deviation alarm is not raised; it clears below the limit minus the hysteresis, or once
        the certain alarm is raised. A rope without a tension is not judged (sensor_fault)."""
        s = self.settings
        thr = s.deviation_frac
        assert thr is not None
        used = [r.t_hat for r in iv if r.present]
        if not used or sum(used) / len(used) < s.deviation_min_mean_dan * DAN_TO_N:
            # unloaded ropes: no check, as the deviation alarm, whose deviation is then 0
            for i in range(len(iv)):
                aid = f"deviation_possible:n{node}:r{i}"
                if aid in self._alarms:
                    self._step(ev, aid, "deviation_possible", node=node, rope=i, timing=s.timing, now_s=now_s,
                               raise_cond=False, clear_cond=True, value=0.0, threshold=thr,
                               message=f"rope {i + 1}: ropes unloaded, no check")
            return
        anchoring = s.band is not None and s.band.anchor
        blind = [k + 1 for k, r in enumerate(iv) if not r.vouched] if anchoring else []
        for i, b in enumerate(deviation_bounds(iv)):
            if b is None:
                continue
            certain = self._alarms.get(f"deviation:n{node}:r{i}")
            certain_on = certain is not None and certain.present
            reach = b.reach
            aid = f"deviation_possible:n{node}:r{i}"
            if aid not in self._alarms and (certain_on or reach < thr):
                continue  # the usual case: skip the message
            if quiet_s:
                why = f" (no frame for {quiet_s:.1f} s)"
            elif not anchoring:
                why = " (the seals' static friction could hold it)"
            elif blind:
                why = f" (rope{'s' if len(blind) > 1 else ''} {','.join(map(str, blind))} not vouched for)"
            else:
                why = ""
            self._step(ev, aid, "deviation_possible", node=node, rope=i, timing=s.timing, now_s=now_s,
                       raise_cond=reach >= thr and not certain_on,
                       clear_cond=reach < thr - s.deviation_hysteresis_frac or certain_on,
                       value=round(b.dev, 4), threshold=thr,
                       message=f"rope {i + 1} {b.dev:+.1%} +-{b.band:.1%} from the mean, may reach {reach:.1%} "
                       f"(limit {thr:.0%}){why}: check the rope tensions at the next landing", band=round(b.band, 4))

    def _step(self, ev: list[AlarmEvent], aid: str, kind: str, *, node: int | None = None, rope: int | None = None,
              timing: Timing, now_s: float, raise_cond: bool, clear_cond: bool, value: float | None = None,
              threshold: float | None = None, message: str, band: float | None = None) -> None:
        """One evaluation of alarm `aid` (created at its condition's first appearance): its debounce
        stepped, a raise or clear appended to `ev`."""
        a = self._alarms.get(aid)
        if a is None:
            if not raise_cond:
                return  # nothing to track until the condition first appears
            a = self._alarms[aid] = _Alarm(aid, kind, node, rope, Debounce(timing))
            if rope is not None and node is not None and (kind in TENSION_KINDS or kind in POSITION_KINDS):
                self._per_rope.setdefault(node, []).append(a)
        a.value, a.threshold, a.band = value, threshold, band
        change = a.debounce.step(now_s, raise_cond, clear_cond)
        if change is None:
            if a.present and not clear_cond:
                a.message = message
                a.worst = _worse(kind, a.worst, value)
            return
        if change == "clear":
            a.cleared_s = now_s
            ev.append(self._event(a, now_s, "clear", f"cleared: {message}"))
        else:
            a.latched = not a.hidden        # a hidden alarm is logged, not annunciated: no ack due
            a.raised_s, a.cleared_s, a.acked_s, a.acked_by = now_s, None, None, None
            a.message = message
            a.worst = value
            ev.append(self._event(a, now_s, "raise"))
            if not a.hidden:
                self._raises.append(now_s)

    @staticmethod
    def _event(a: _Alarm, now_s: float, action: str, message: str | None = None,
               operator: str | None = None) -> AlarmEvent:
        return AlarmEvent(time_s=now_s, action=action, alarm=a.id, kind=a.kind, node=a.node, rope=a.rope,
                          value=a.value, threshold=a.threshold, message=message if message is not None else a.message,
                          worst=a.worst, operator=operator, annunciated=not a.hidden)

    def _log(self, ev: list[AlarmEvent]) -> list[AlarmEvent]:
        self.events.extend(ev)
        return ev
