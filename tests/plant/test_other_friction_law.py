"""The pluggable friction law: a hoist plant with Coulomb-Stribeck seals runs through the same kernel."""
import tomllib

import numpy as np

from ropemon.lab.plant.friction import CoulombStribeck
from ropemon.lab.plant.stepper import Stepper
from ropemon.lab.plant.run import simulate
from ropemon.lab.plant.scenario import build
from ropemon.lab.plant.solver import GAMMA


def _short_cs(scenarios_dir):
    path = scenarios_dir / "short-test.toml"
    doc = tomllib.loads(path.read_text())
    fr = doc["plant"]["friction"]
    del fr["sigma0"], fr["sigma1"]
    fr["law"] = "coulomb-stribeck"
    fr["v_threshold"] = 1e-4
    return build(doc, path)


def test_coulomb_stribeck_plant(scenarios_dir):
    sc = _short_cs(scenarios_dir)
    assert isinstance(sc.plant.friction, CoulombStribeck)
    p, u = sc.plant, sc.inputs
    st = Stepper(p, u)
    y = p.rest_state(u)
    y[p.iv] = [0.002, -0.001, 0.0, 5e-5]
    f, J = p.rhs(u, 5, y, True)
    fk, jac = st.rhs(5, list(y), True)
    assert np.allclose(fk, f, rtol=1e-12)
    b = np.arange(p.size, dtype=float) + 1.0
    c = GAMMA * 0.0025
    assert np.allclose(st.solve(st.factor(jac, c), list(b)), np.linalg.solve(np.eye(p.size) - c * J, b), rtol=1e-8)
    res = simulate(sc)
    tr = res.truth
    k = len(res.t) - 1
    # at the final rest the balance holds and the seals hold a share of the load
    assert np.allclose(tr["tension_N"][k], tr["p_cav_Pa"][k] * p.A + tr["friction_N"][k], atol=5.0)
    assert np.abs(tr["friction_N"][k]).max() > 100.0
