"""Write a simulation's results: sensors.rsens, truth.npz, truth.json, node.json (docs/data-formats.md)."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from ropemon.lab.plant.run import Result
from ropemon.lab.plant.sensors import sensor_records
from ropemon.commission.reference import RS, RSENS_HEADER  # read them back with reference.read_rsens

# truth array -> (unit, meaning); signs as docs/model.md
TRUTH_ARRAYS = {
    "t_s": ("s", "sample time, k / sample_hz"),
    "tension_N": ("N", "rope-end tension T_i at the piston rod"),
    "friction_N": ("N", "seal friction F_i (sign of v_i); T = p_cav A + F"),
    "z_m": ("m", "friction-law internal state (LuGre, elasto-plastic: bristle deflection; Maxwell-slip: "
                 "sum k_j z_j / sum k_j; Coulomb-Stribeck: unused, 0)"),
    "z_elements_m": ("m", "Maxwell-slip only: element deflections z_j, third axis = element"),
    "p_cav_Pa": ("Pa", "cavity pressure"),
    "p_tap_Pa": ("Pa", "pressure at the sensor tap, p_cav - dp(q)"),
    "p_junction_Pa": ("Pa", "pressure in the connecting assembly"),
    "piston_x_m": ("m", "piston position, + = pulled out by the rope"),
    "piston_v_m_s": ("m/s", "piston velocity"),
    "flow_piston_m3_s": ("m^3/s", "Q_i = A_i v_i, + = out of the cavity"),
    "flow_pipe_m3_s": ("m^3/s", "flow in the pipe from cavity i to the assembly, + = out of the cavity"),
    "cage_depth_m": ("m", "cage depth, + downwards (hoist rig)"),
    "cage_speed_m_s": ("m/s", "cage speed, + = going down (hoist rig)"),
    "cage_accel_m_s2": ("m/s^2", "cage acceleration (hoist rig)"),
    "wheel_depth_m": ("m", "rope paid out by the wheel, as cage depth without rope stretch (hoist rig)"),
    "wheel_speed_m_s": ("m/s", "wheel surface speed (hoist rig)"),
    "wheel_accel_m_s2": ("m/s^2", "wheel acceleration (hoist rig)"),
    "load_N": ("N", "static load: (cage + payload + hanging tail rope) g, or the sum of bench loads"),
    "load_input_N": ("N", "bench rig: prescribed load force per cylinder"),
    "payload_kg": ("kg", "payload in the cage"),
    "oil_temp_C": ("C", "oil temperature"),
    "pump_m3_s": ("m^3/s", "bench rig: pump flow into the connecting line"),
    "end_stop_N": ("N", "end-stop contact force on the piston along x (< 0 at the extended end, > 0 at the "
                        "retracted end, 0 off the stops)"),
    "valve_open": ("1", "rope's stop valve: 1 open, 0 closed (between only while it closes)"),
    "seal_scale": ("1", "seal force scale relative to the seal type (force_scale; a seized seal's factor)"),
    "leak_m3_s": ("m^3/s", "oil leak flow out of the device, all leaks"),
    "leaked_m3": ("m^3", "oil leaked since the start, cumulative"),
    "rope_offset_m": ("m", "effective rope length excess delta_i (offsets, groove creep, creep per wind; hoist rig)"),
}


def fault_events(res: Result) -> dict[str, Any]:
    """Physical events read off the truth: each rope's first end-stop contact (s, None: never)."""
    E = res.truth.get("end_stop_N")
    out: dict[str, Any] = {"end_stop_first_contact_s": None}
    if E is not None:
        first = []
        for i in range(E.shape[1]):
            hit = np.nonzero(E[:, i] != 0.0)[0]
            first.append(float(res.t[hit[0]]) if len(hit) else None)
        out["end_stop_first_contact_s"] = first
    return out


def write_rsens(path: Path, records: np.ndarray, sample_hz: int) -> None:
    n = (records.shape[1] - 4) // 2
    with open(path, "wb") as f:
        f.write(RSENS_HEADER.pack(RS.MAGIC, 1, n, sample_hz, 0))
        f.write(records.astype("<u2").tobytes())


def node_physical(res: Result) -> tuple[dict[str, Any], str]:
    """The `physical` config for the scenario's site, and where its friction came from."""
    from ropemon.commission.site import SiteError, physical_from_site

    site = res.scenario.site
    try:
        physical, source = physical_from_site(site), f"site friction file {site.friction_path}"
    except SiteError as e:
        fit = getattr(res.scenario.plant.friction, "as_fit", None)
        if fit is None:
            raise
        physical = physical_from_site(site, fit())
        source = f"plant's true friction (site friction unusable: {e})"
    # The node boots at the site's start depth (SITE.toml [hoist] start_depth_m), as a real one
    # does, never at the simulated cage's: a scenario that starts the cage elsewhere shows the
    # node's depth off by the difference.
    return physical, source


def _jsonable(x: Any) -> Any:
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return _jsonable(dataclasses.asdict(x))
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, (str, int, float, bool)) or x is None:
        return x
    return str(x)


def write_outputs(res: Result, out_dir: Path | str, summary: dict[str, Any]) -> list[Path]:
    """Write every output file into out_dir; returns the paths written."""
    sc = res.scenario
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    arrays = {"t_s": res.t, **res.truth}
    np.savez_compressed(out / "truth.npz", **arrays)
    written.append(out / "truth.npz")
    meta: dict[str, Any] = {
        "schema": 1, "scenario": sc.name, "scenario_file": str(sc.path), "rig": sc.rig, "seed": sc.seed,
        "sample_hz": sc.sample_hz, "step_s": sc.step_s, "duration_s": sc.duration_s, "ropes": sc.plant.n,
        "cylinder_area_m2": sc.plant.A, "rated_rope_tension_N": sc.rated_rope_tension_N,
        "site_file": str(sc.site.path) if sc.site is not None else None,
        "phases": [{"kind": p.kind, "label": p.label, "t0_s": p.t0, "t1_s": p.t1} for p in sc.phases],
        "hidden": sc.hidden, "cage_mass_kg": sc.cage_mass_kg,
        "tail": None if sc.tail is None else {"count": sc.tail.count, "kg_per_m": sc.tail.kg_per_m,
                                              "loop_depth_m": sc.tail.loop_depth_m},
        "arrays": {k: {"unit": TRUTH_ARRAYS.get(k, ("", ""))[0], "meaning": TRUTH_ARRAYS.get(k, ("", ""))[1],
                       "shape": list(v.shape)} for k, v in arrays.items()},
        "scenario_doc": sc.doc, "summary": summary,
        "faults": sc.faults,
        "end_stops": None if sc.plant.end_stops is None else {
            "half_stroke_m": list(sc.plant.end_stops.half_stroke_m),
            "stiffness_N_m": sc.plant.end_stops.stiffness_N_m, "damping_N_s_m": sc.plant.end_stops.damping_N_s_m},
        "fault_events": fault_events(res),
    }
    if sc.site is not None and sc.sensors is not None:
        from ropemon.commission.nodejson import make_node_json, write_node_json

        physical, source = node_physical(res)
        node = make_node_json(physical, node_id=sc.site.node_id, key=sc.site.key)  # as `ropemon config` would
        write_node_json(out / "node.json", node)
        written.append(out / "node.json")
        rng = np.random.default_rng(sc.seed)
        records = sensor_records(sc.sensors, physical, res.t, res.truth, rng)
        write_rsens(out / "sensors.rsens", records, sc.sample_hz)
        written.append(out / "sensors.rsens")
        meta["node_friction_source"] = source
        meta["node_physical"] = physical
        meta["sensors"] = sc.sensors
    (out / "truth.json").write_text(json.dumps(_jsonable(meta), indent=1) + "\n")
    written.append(out / "truth.json")
    return written
