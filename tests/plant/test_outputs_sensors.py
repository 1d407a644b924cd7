"""`ropemon simulate` outputs: .rsens as docs/data-formats.md, truth, node.json; sensor models and faults."""
import json

import numpy as np
import pytest

from ropemon.cli import main
from ropemon.commission.reference import read_rsens
from ropemon.lab.plant.sensors import Fault, SensorSpec, sensor_records


@pytest.fixture(scope="module")
def short_out(tmp_path_factory, scenarios_dir):
    out = tmp_path_factory.mktemp("short")
    assert main(["simulate", str(scenarios_dir / "short-test.toml"), "--out", str(out), "--quiet"]) == 0
    return out


def _counts_to(ch_lo, ch_hi, c_lo, c_hi, counts):
    return ch_lo + (counts.astype(float) - c_lo) / (c_hi - c_lo) * (ch_hi - ch_lo)


def test_files_and_header(short_out):
    for f in ("sensors.rsens", "truth.npz", "truth.json", "node.json"):
        assert (short_out / f).stat().st_size > 0
    raw = (short_out / "sensors.rsens").read_bytes()
    assert raw[:4] == b"RSNS"
    assert int.from_bytes(raw[4:6], "little") == 1 and int.from_bytes(raw[6:8], "little") == 4
    assert int.from_bytes(raw[8:10], "little") == 200 and raw[10:12] == b"\0\0"
    n, hz, rec = read_rsens(short_out / "sensors.rsens")
    truth = np.load(short_out / "truth.npz")
    assert rec.shape == (len(truth["t_s"]), 2 * 4 + 4)
    assert np.allclose(truth["t_s"], np.arange(len(rec)) / hz)


def test_sensor_counts_read_back_to_the_truth(short_out):
    """The node's scales from node.json turn the counts back into tap pressure and piston position."""
    _, _, rec = read_rsens(short_out / "sensors.rsens")
    truth = np.load(short_out / "truth.npz")
    ph = json.loads((short_out / "node.json").read_text())["physical"]
    for i, ch in enumerate(ph["pressure_channels"]):
        p = _counts_to(4.0, 20.0, ch["counts_4mA"], ch["counts_20mA"], rec[:, i])
        p_pa = ch["range_Pa"][0] + (p - 4.0) / 16.0 * (ch["range_Pa"][1] - ch["range_Pa"][0])
        err = p_pa - truth["p_tap_Pa"][:, i]
        assert abs(err.mean()) < 2e3 and err.std() < 1e4        # 5 kPa noise, 1.3 kPa per count
    for i, ch in enumerate(ph["displacement_channels"]):
        x = _counts_to(ch["range_m"][0], ch["range_m"][1], ch["counts_lo"], ch["counts_hi"], rec[:, 4 + i])
        assert np.abs(x - truth["piston_x_m"][:, i]).max() < 1e-4
    assert np.all(rec[:, 9] == 0xFFFF)                            # no temperature input on this site
    volts = rec[:, 8] * ph["battery_V_per_count"]
    assert 3.8 < volts.mean() < 4.1


def test_speed_counter_and_hall_marks(short_out):
    _, _, rec = read_rsens(short_out / "sensors.rsens")
    truth = np.load(short_out / "truth.npz")
    ph = json.loads((short_out / "node.json").read_text())["physical"]
    pulses = rec[:, 10].astype(np.int64)
    pulses = np.where(pulses > 32767, pulses - 65536, pulses)     # signed counter
    moved = truth["cage_depth_m"] - truth["cage_depth_m"][0]
    assert np.abs(pulses * ph["speed_m_per_pulse"] - moved).max() <= ph["speed_m_per_pulse"] + 1e-9
    assert pulses[-1] > 250                                        # went 3 m down: positive
    # the cage starts at the 2 m mark and creeps away from it
    assert rec[0, 11] & 1 and not rec[-1, 11] & 1


def test_node_json_is_a_complete_node_config(short_out):
    from ropemon.commission.nodejson import make_node_json

    doc = json.loads((short_out / "node.json").read_text())
    assert doc["schema"] == 1 and isinstance(doc["crc"], int) and doc["node"]
    assert make_node_json(doc["physical"], node_id=doc["node"]["node_id"], key=bytes(doc["node"]["key"])) == doc
    meta = json.loads((short_out / "truth.json").read_text())
    assert meta["scenario"] == "short-test" and meta["sample_hz"] == 200
    assert meta["hidden"]["friction_law"] == "lugre"
    assert set(meta["arrays"]) >= {"tension_N", "p_tap_Pa", "p_cav_Pa", "friction_N", "piston_x_m",
                                   "cage_depth_m", "flow_pipe_m3_s"}


def test_node_boots_at_the_sites_start_depth_and_tracks_the_cage_from_there(short_out):
    """The node config starts at the site's start depth (SITE.toml), never at the simulated
    cage's; the node's depth then follows the cage's travel from there."""
    from ropemon.commission import reference
    from ropemon.commission.site import load_site

    doc = json.loads((short_out / "node.json").read_text())
    truth = np.load(short_out / "truth.npz")
    meta = json.loads((short_out / "truth.json").read_text())
    start = load_site(meta["site_file"]).hoist.start_depth_m
    assert doc["physical"]["start_depth_m"] == start
    offset = start - truth["cage_depth_m"][0]
    from ropemon.firmware import node_module

    Node = node_module("node").Node
    parse = node_module("config").parse
    import array

    node = Node(parse(doc))
    kernel = node_module("kernel")
    _, _, rec = reference.read_rsens(short_out / "sensors.rsens")
    worst = 0.0
    for k, row in enumerate(rec):
        node.sample(array.array("H", row.tolist()))
        if k % 50 == 49:
            worst = max(worst, abs(node.S[kernel.DEPTH_MM] / 1000.0 - offset - truth["cage_depth_m"][k]))
    assert worst < 0.5, worst


PHYS = {"ropes": 2, "adc_bits": 16, "battery_V_per_count": 0.00025, "temperature": None,
        "speed_m_per_pulse": 0.01, "hall_marks_m": [1.0],
        "pressure_channels": [{"counts_4mA": 4800, "counts_20mA": 24000, "range_Pa": [0.0, 25e6]}] * 2,
        "displacement_channels": [{"counts_lo": 4800, "counts_hi": 24000, "range_m": [-0.1, 0.1]}] * 2}


def _records(faults):
    spec = SensorSpec(pressure_noise_Pa=0.0, displacement_noise_m=0.0, adc_noise_counts=0.0, battery_V=4.0,
                      battery_drain_V_per_h=0.0, battery_noise_V=0.0, temperature_noise_C=0.0,
                      hall_half_width_m=0.05, hall_spacing_m=0.04, faults=tuple(faults))
    t = np.arange(1000) / 100.0
    truth = {"p_tap_Pa": np.full((1000, 2), 5e6) + np.linspace(0, 1e6, 1000)[:, None],
             "piston_x_m": np.zeros((1000, 2)), "cage_depth_m": np.linspace(0.0, -2.0, 1000)}
    return t, sensor_records(spec, PHYS, t, truth, np.random.default_rng(0))


def test_faults_open_loop_stuck_drift_spike():
    t, clean = _records([])
    _, rec = _records([Fault("open_loop", "pressure", 0, 2.0, 3.0), Fault("stuck", "pressure", 1, 5.0, 6.0),
                       Fault("drift", "displacement", 0, 4.0, 1e18, drift_per_s=0.01),
                       Fault("spike", "displacement", 1, 0.0, 1e18, spike_size=0.05, spike_rate_hz=5.0)])
    ol = (t >= 2.0) & (t < 3.0)
    assert np.all(rec[ol, 0] < 4320) and np.all(rec[~ol, 0] == clean[~ol, 0])   # below NAMUR 3.6 mA
    st = (t >= 5.0) & (t < 6.0)
    assert np.ptp(rec[st, 1]) == 0 and np.ptp(clean[st, 1]) > 0
    dr = t >= 4.0
    assert rec[-1, 2] - clean[-1, 2] == pytest.approx((9.99 - 4.0) * 0.01 / 0.2 * 19200, abs=2)
    assert np.all(rec[~dr, 2] == clean[~dr, 2])
    spikes = rec[:, 3] != clean[:, 3]
    assert 20 < spikes.sum() < 100                                           # ~5 Hz over 10 s
    # speed: the cage goes up (depth decreasing) -> the counter counts down, modulo 2**16
    assert rec[-1, 6] == 65536 - 200


def test_seed_changes_the_noise_not_the_truth(tmp_path, scenarios_dir):
    outs = []
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        out = tmp_path / name
        assert main(["simulate", str(scenarios_dir / "short-test.toml"), "--out", str(out), "--seed", str(seed),
                     "--quiet"]) == 0
        outs.append((read_rsens(out / "sensors.rsens")[2], np.load(out / "truth.npz")["tension_N"]))
    (ra, ta), (rb, tb), (rc, tc) = outs
    assert np.array_equal(ra, rb) and np.array_equal(ta, tb)     # reproducible
    assert np.array_equal(ta, tc) and not np.array_equal(ra[:, :4], rc[:, :4])
