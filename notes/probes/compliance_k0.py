"""The node as commissioned against the same node with k = 0, on run directories `ropemon evaluate`
left (DIR/population/population-N or DIR/runs/SCENARIO), and what the commissioning wind shows.

    PYTHONPATH=host .venv/bin/python notes/probes/compliance_k0.py out/evaluate/population/population-1?? \
        out/evaluate/runs/paper-field-trip ...

Per wind: `ropemon fit-compliance --site`'s own check of the fit on the commissioning wind (`check_fit`,
against the config with k = 0), the share of that wind where every piston kept its line of position on
pressure (the fit's `used_fraction`), each piston's departure from its k_i p_i there (rms of x_i - k_i p_i,
each PIECE_S piece about its mean, over the rms of k_i p_i), and the firmware's figures on the scored
wind (worst-rope RMS and peak, % of rated; the empty-cage pithead total, %; the station's counted
healthy-wind alarm raises) with the commissioned config and with only its k set to 0 (the observer's
other settings, which the compliance fit chose, kept). A research probe, not a product check.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ropemon.commission import compliance as C
from ropemon.commission.nodejson import make_node_json, write_node_json
from ropemon.lab import evaluate as EV
from ropemon.lab import metrics as M
from ropemon.lab import population as P
from ropemon.lab.rundir import RunDir


def departures(ph: dict, records: np.ndarray, k) -> list[float]:
    n, fs = int(ph["ropes"]), float(ph["sample_hz"])
    b = max(1, int(round(C.BLOCK_S * fs)))
    pp, xx = [], []
    for i in range(n):
        p, x, ok, _, _ = C._scaled(ph, records, i)
        pp.append(C._blocks(p, ok, b))
        xx.append(C._blocks(x, ok, b))
    pp, xx = np.array(pp), np.array(xx)
    valid = ~np.isnan(pp).any(axis=0) & ~np.isnan(xx).any(axis=0)
    pieces = C._pieces(valid, max(2, int(round(C.PIECE_S / (b / fs)))))
    out = []
    for i in range(n):
        dv = np.concatenate([xx[i, j] - xx[i, j].mean() for j in pieces])
        dq = np.concatenate([k[i] * (pp[i, j] - pp[i, j].mean()) for j in pieces])
        out.append(float(np.sqrt(np.mean((dv - dq) ** 2)) / np.sqrt(np.mean(dq ** 2))))
    return out


def figures(wd: Path, ph: dict, tag: str) -> dict:
    run = RunDir(wd)
    nj = wd / f"node-{tag}.json"
    write_node_json(nj, make_node_json(ph, **run.identity))
    frames = EV.firmware_frames(ph, run.sensors_path, wd, nj, f"frames-{tag}.bin")
    hz = run.sample_hz
    w = hz // int(ph["frame_hz"])
    tr = np.asarray(run.truth["tension_N"], float)
    n = min(len(frames), len(tr) // w)
    rated = float(ph["rated_rope_tension_N"])
    phase, exc, steady, pay = EV.scoring_masks(run.truth, tr, hz, rated, float(ph["hall_marks_m"][-1]))
    fig = M.evaluate_estimate(EV.frame_means_n(frames)[:n], M.window_means(tr[: n * w], w), rated, phase[: n * w: w],
                              M.window_means(exc.astype(float), w)[:n] > 0,
                              M.window_means(steady.astype(float), w)[:n] == 1.0, M.window_means(pay, w)[:n])
    times, d, _valid, _hidden = P.frame_truth(run.truth, frames, hz, ph)
    ev = P.station_events(frames[: len(times)], P.station_settings(ph)["station"])
    wind = (P.wind_phases(run.meta) or [(0.0, float(times[-1]))])[0]
    hf = M.healthy_alarm_figures(ev, wind, float(times[-1]), times, np.abs(d) > M.DEVIATION_LIMIT)
    return {"rms": fig["rope_rms_pct"], "peak": fig["rope_peak_pct"], "pithead": fig["pithead_total_pct"],
            "raised": hf["raised"]}


def main(dirs: list[str]) -> None:
    print("| wind | check | lines held (used_fraction) | departure per rope | RMS % | peak % | pithead % | raised | k = 0: RMS % | peak % "
          "| pithead % | raised |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for d in dirs:
        wd = Path(d)
        run = RunDir(wd)
        ph = dict(run.physical)
        if not any(ph.get("hydraulic_compliance_m_per_Pa") or []):
            print(f"| {wd.name} | no compliance | | | | | | | | | | |")
            continue
        k0 = dict(ph, hydraulic_compliance_m_per_Pa=[0.0] * int(ph["ropes"]))
        k0.pop("observer_compliance", None)
        cw = RunDir(wd / "commissioning-wind")
        recs = cw.records
        res = C.fit(k0, recs)
        chk = C.check_fit(k0, recs, res, C.known_load(Path(cw.meta["site_file"]), None, k0))
        dep = departures(k0, recs, res.k_m_per_pa)
        a, b = figures(wd, ph, "asis"), figures(wd, k0, "k0")
        print(f"| {wd.name} | {chk.verdict} | {res.used_fraction:.2f} | {', '.join(f'{x:.2f}' for x in dep)} | {a['rms']:.2f} | {a['peak']:.2f} "
              f"| {a['pithead']:+.2f} | {a['raised']} | {b['rms']:.2f} | {b['peak']:.2f} | {b['pithead']:+.2f} "
              f"| {b['raised']} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
