"""The trip report's rest figures are taken over the windows docs/operator.md and report.py name:
on arrival the REST_AVG_S (5 s) after the cage settled (SETTLE_S, 1 s, after it stopped); on
departure the last 5 s before it left. A hand-built stream whose tension steps every second
of each rest tells which seconds a figure averaged: a window shifted by a second or more
gives another figure. The report (`trips_from_store`) and the web's trip page (logread) alike."""
import pytest

from ropemon.station.protocol import Rope, decode_raw, encode_frame
from ropemon.station.report import trips_from_store
from ropemon.station.store import Store
from ropemon.station.web import logread

AREA = 0.0314
LEAVE_S = 20.0        # the cage leaves the pithead (first moving frame)
ARRIVE_S = 70.0       # and stands at the bottom from here (first frame at rest)
END_S = 100.0


def tension_n(k: int) -> int:
    """Every rope's compensated tension (N) of frame k (at k / 10 s): steps of 1 kN per second,
    counted from the start at the pithead and from the arrival at the bottom; 90 kN during the
    bounce of the first second after arriving."""
    if k < LEAVE_S * 10:
        return 40_000 + 1000 * (k // 10)                 # 40 kN in second 0 .. 59 kN in second 19
    if k < ARRIVE_S * 10:
        return 45_000
    sec = (k - int(ARRIVE_S * 10)) // 10                 # whole seconds since arriving
    return 90_000 if sec == 0 else 50_000 + 1000 * sec


def logged(tmp_path):
    db = tmp_path / "log.db"
    with Store(db) as st:
        for k in range(int(END_S * 10)):
            t = k / 10
            moving = LEAVE_S <= t < ARRIVE_S
            depth_mm = 16 * min(max(k - int(LEAVE_S * 10), 0), int((ARRIVE_S - LEAVE_S) * 10)) * 100  # 16 m/s
            c = tension_n(k) // 10
            raw, _ = encode_frame(node=1, seq=k, time_ms=k * 100, depth_mm=depth_mm,
                                  speed_mm_s=16_000 if moving else 0, battery_mv=12000,
                                  ropes=[Rope(c, c, c, 1000)] * 4)
            st.add_frame("pithead", decode_raw(raw), 1_760_000_000.0 + t)
    return db


def mean_kn(first_s: int, last_s: int) -> float:
    """The mean of the arrival rest's seconds first_s .. last_s (whole seconds after arriving)."""
    return sum(50 + s for s in range(first_s, last_s + 1)) / (last_s - first_s + 1)


def test_the_arrival_figure_is_the_5_s_after_the_settling_second(tmp_path):
    db = logged(tmp_path)
    with Store(db, readonly=True) as st:
        (trip,) = trips_from_store(st, [AREA] * 4, 810)
    end = trip.end
    assert trip.direction == "pithead -> bottom" and end.where == "bottom"
    # seconds 1 .. 5 after arriving: 51 .. 55 kN, 53 kN; 5 s later it would be 58 kN, 1 s 54 kN
    assert end.comp_n / 1000 == pytest.approx([mean_kn(1, 5)] * 4, abs=1e-9)
    assert end.frames == 50
    assert end.t_s == pytest.approx(ARRIVE_S + 3.45)     # the middle of 71.0 .. 75.9 s
    assert end.depth_m == pytest.approx(800.0)


def test_the_departure_figure_is_the_last_5_s_before_leaving(tmp_path):
    db = logged(tmp_path)
    with Store(db, readonly=True) as st:
        (trip,) = trips_from_store(st, [AREA] * 4, 810)
    start = trip.start
    assert start.where == "pithead"
    # seconds 15 .. 19: 55 .. 59 kN, 57 kN (a frame at exactly 5 s before the last may be counted
    # or not, by rounding: 56.94 kN); a second earlier it would be 56 kN
    assert start.comp_n / 1000 == pytest.approx([57.0] * 4, abs=0.07)
    assert start.frames in (50, 51)
    assert start.t_s == pytest.approx(LEAVE_S - 0.1 - 2.45, abs=0.06)


def test_the_web_trip_page_takes_the_same_rest_windows(tmp_path):
    db = logged(tmp_path)
    with Store(db, readonly=True) as st:
        (tr,) = st.trips()
        report = logread.trip_detail(st, tr.id, [AREA] * 4, 810.0)["report"]
    assert report.end.comp_n / 1000 == pytest.approx([mean_kn(1, 5)] * 4, abs=1e-9)
    assert report.start.comp_n / 1000 == pytest.approx([57.0] * 4, abs=0.07)
