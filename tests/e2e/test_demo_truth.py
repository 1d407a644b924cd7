"""The demo's comparison with the simulator's truth: frames aligned by node time."""
import numpy as np
import pytest

from ropemon.lab.demo import accuracy, window_truth
from ropemon.station.protocol import Rope, decode_raw, encode_frame

HZ, WIN = 200, 20
AREA = [0.03] * 4


def truth(n=4000):
    t = np.arange(n) / HZ
    tension = np.stack([30_000 + 1000 * np.sin(t + i) + 50 * t for i in range(4)], axis=1)
    return {"t_s": t, "tension_N": tension, "cage_speed_m_s": np.zeros(n), "cage_depth_m": np.zeros(n)}


def test_window_truth_is_the_mean_of_the_frames_own_samples():
    tr = truth()
    # A frame stamped (k + 1) / HZ closes the window of samples k - 19 .. k.
    k = 999
    got = window_truth(tr["tension_N"], tr["t_s"], np.array([(k + 1) / HZ]), WIN / HZ)
    assert got[0] == pytest.approx(tr["tension_N"][k - 19: k + 1].mean(axis=0))


def frames_from(tr, shift=0, bias_n=0.0):
    out = []
    for j in range(len(tr["t_s"]) // WIN):
        k = (j + 1) * WIN - 1 + shift
        if k >= len(tr["t_s"]) or k < WIN:
            continue
        m = tr["tension_N"][k - WIN + 1: k + 1].mean(axis=0) + bias_n
        ropes = [Rope(int(round(v / 10)), 0, 0, int(round(v / AREA[i] / 1000))) for i, v in enumerate(m)]
        raw, _ = encode_frame(node=1, seq=j, time_ms=((j + 1) * WIN) * 1000 // HZ, ropes=ropes)
        out.append(decode_raw(raw))
    return out


def test_aligned_frames_have_only_quantisation_error_and_misalignment_shows():
    tr = truth()
    good = accuracy(frames_from(tr), tr, tr["t_s"], AREA, 80_000, WIN / HZ)
    assert good["compensated"]["rope_peak_pct"] < 5 / 80_000 * 100 * 1.01   # 1 daN rounding
    late = accuracy(frames_from(tr, shift=WIN), tr, tr["t_s"], AREA, 80_000, WIN / HZ)
    assert late["compensated"]["rope_rms_pct"] > 10 * good["compensated"]["rope_rms_pct"]
    biased = accuracy(frames_from(tr, bias_n=800.0), tr, tr["t_s"], AREA, 80_000, WIN / HZ)
    assert biased["compensated"]["rope_rms_pct"] == pytest.approx(1.0, abs=0.01)     # 800 N of 80 kN
    assert biased["compensated"]["total_rms_pct"] == pytest.approx(1.0, abs=0.01)


def test_frames_with_a_failed_sensor_are_counted_not_compared():
    tr = truth(400)
    fs = frames_from(tr)
    raw, _ = encode_frame(node=1, seq=99, time_ms=1000, ropes=[Rope(-32768, -32768, -32768, 0xFFFF)] + [Rope(3000, 0, 0, 1000)] * 3)
    acc = accuracy(fs + [decode_raw(raw)], tr, tr["t_s"], AREA, 80_000, WIN / HZ)
    assert acc["frames"] == len(fs) and acc["frames_with_failed_sensor"] == 1
