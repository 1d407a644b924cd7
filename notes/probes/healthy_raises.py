"""Rerun the firmware as the code builds it now on every wind of a population run directory, with
`physical` overrides (key=JSON value ...), and score the station's alarms: each hoist's healthy
raises that count, its silent ropes, its fault's outcome; the total healthy raises per wind.

    .venv/bin/python notes/probes/healthy_raises.py out/evaluate/population
    .venv/bin/python notes/probes/healthy_raises.py out/evaluate/population friction_warmup_s=0

(out/evaluate/population: left by `make evaluate`; the tuning hoists' by `ropemon evaluate
--population 20 --seeds tuning --faults --out DIR`, in DIR/population.)"""
import sys, json, tempfile
from pathlib import Path
from multiprocessing import Pool
import numpy as np
from ropemon.commission.nodejson import make_node_json, write_node_json
from ropemon.lab import evaluate as EV, population as P, metrics as M
from ropemon.lab.rundir import RunDir

work = Path(sys.argv[1])
over = dict(a.split("=", 1) for a in sys.argv[2:])
over = {k: json.loads(v) for k, v in over.items()}


def one(d):
    seed = int(d.name.split("-")[-1])
    out = {"seed": seed}
    try:
        run = RunDir(d)
        ph = dict(run.physical); ph.update(over)
        settings = P.station_settings(ph)
        with tempfile.TemporaryDirectory() as td:
            nj = Path(td) / "node.json"; write_node_json(nj, make_node_json(ph, **run.identity))
            fr = EV.firmware_frames(ph, run.sensors_path, Path(td), nj)
            sc = P.score_alarms(fr, run.truth, run.meta, run.sample_hz, ph, settings)
            out["healthy"] = sc["station"]["healthy"]["raised"]
            out["kinds"] = sc["station"]["healthy"]["kinds"]
            out["silent"] = sc["station"]["silent"]
            fd = d / "fault"
            if (fd / "frames.bin").exists():
                f = P.draw_fault(seed, P.draw(seed))
                frun = RunDir(fd)
                ff = EV.firmware_frames(ph, frun.sensors_path, Path(td), nj, "ff.bin")
                fs = P.score_alarms(ff, frun.truth, frun.meta, frun.sample_hz, ph, settings, f, healthy=run.truth)
                out["fault"] = {"class": f.kind, "crossed": fs["truth"].get("crossed"),
                                "in_time": fs["station"]["fault"].get("in_time"),
                                "latency": fs["station"]["fault"].get("latency_s"),
                                "silent": fs["station"]["silent"]}
    except Exception as e:  # a probe: report and go on
        out["error"] = f"{type(e).__name__}: {e}"
    return out


if __name__ == "__main__":
    dirs = sorted(p for p in work.glob("population-*") if (p / "frames.bin").exists())
    with Pool(2) as pool:
        res = pool.map(one, dirs)
    tot = 0
    for r in res:
        print(json.dumps(r))
        tot += r.get("healthy", 0)
    n = sum(1 for r in res if "healthy" in r)
    print(f"healthy raises {tot} on {n} winds: {tot / max(n, 1):.3f} per wind")
