"""The web benchmark's premises (`ropemon bench web`): every value the live page shows names its frame,
and the simulated wind the browser tests and the benchmark play is a wind."""
from __future__ import annotations

from web_rig import js_fixed

from ropemon.lab.bench.web import CodedWind, _code
from ropemon.lab.webstation import Wind, kn


def test_each_frame_of_the_coded_wind_is_named_by_what_the_page_shows_of_ropes_1_and_2():
    wind = CodedWind(1, bytes(16), seed=3)
    seen = []
    for k in range(400):
        seq, dan, _, _, _ = wind.frame(k / 10)
        a, b = js_fixed(kn(dan[0]), 1), js_fixed(kn(dan[1]), 1)   # as app.js writes them
        assert _code(a, b) == seq % 100
        seen.append((a, b))
    # two frames in a row never show the same text: every frame is a change in the DOM
    assert all(x != y for x, y in zip(seen, seen[1:]))


def test_the_wind_goes_up_loaded_and_down_empty():
    w = Wind(1, bytes(16), shaft_m=30.0, v_max=5.0, accel=2.5, rest_s=6.0)
    cycle = 2 * (w.rest_s + w.t_trip)
    depth = [w.kinematics(k / 10)[0] for k in range(int(cycle * 10))]
    speed = [w.kinematics(k / 10)[1] for k in range(int(cycle * 10))]
    assert depth[0] == 30.0 and min(depth) == 0.0 and max(speed) == 5.0 and min(speed) == -5.0
    assert all(abs(a - b) <= 0.5 + 1e-9 for a, b in zip(depth, depth[1:]))       # 5 m/s at most, 0.1 s apart
    up = sum(w.frame(t)[1][0] for t in (9.0, 9.5))                                # cruising up, loaded
    down = sum(w.frame(t)[1][0] for t in (23.0, 23.5))                            # cruising down, empty
    assert up > down
