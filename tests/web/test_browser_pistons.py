"""The pistons on the live page in a real browser: each cylinder drawn with its end stops, its
stroke margins and the piston, moved as the frames' positions move; the hoist's standing status
as status; a piston in its margin raises STROKE LIMIT in the alarm list.

One station (`ropemon serve`, one hoist) fed version 3 frames through a pty: the simulated
wind's frames, each re-encoded with the piston positions this test sets (the example site's
cylinders: 100 mm stroke, 10 mm margin).
"""
from __future__ import annotations

import threading

import pytest
from selenium.webdriver.common.by import By
from web_rig import SHORT_WIND, save_screenshot, wait_for

from ropemon.lab.webstation import WebStation, Wind
from ropemon.station.protocol import L, decode_raw, decode_wire, encode_frame

HOIST = "north"
STROKE_MM, MARGIN_MM = 100.0, 10.0      # example_physical: the site the station is configured with
X0, W = 10.0, 180.0                     # the drawn stroke in the cylinder's SVG (templates/_macros.html)


class PistonWind(Wind):
    """The simulated wind, its frames carrying piston positions set by the test (0.1 mm)."""

    def __init__(self, *a, **kw) -> None:
        super().__init__(*a, **kw)
        self.pos_01mm = [12, -35, 80, -5]
        self.lock = threading.Lock()

    def set_position(self, rope: int, pos_01mm: int) -> None:
        with self.lock:
            self.pos_01mm[rope] = pos_01mm

    def frame(self, t_s):
        seq, dan, depth_mm, speed_mm_s, wire = super().frame(t_s)
        f = decode_raw(decode_wire(wire), {self.node: self.key})
        with self.lock:
            pos = list(self.pos_01mm)
        margin = int(MARGIN_MM * 10)
        half = int(STROKE_MM * 5)
        mask = 0
        for i, p in enumerate(pos):
            if p <= -half + margin:
                mask |= 1 << (L.STROKE_LOW_SHIFT + i)
            if p >= half - margin:
                mask |= 1 << (L.STROKE_HIGH_SHIFT + i)
        ropes = [(r.mean_dan, r.min_dan, r.max_dan, r.raw_kpa, p) for r, p in zip(f.ropes, pos)]
        _, wire = encode_frame(node=f.node, seq=f.seq, time_ms=f.time_ms, ropes=ropes, depth_mm=f.depth_mm,
                               speed_mm_s=f.speed_mm_s, battery_mv=f.battery_mv, key=self.key, stroke_mask=mask,
                               status=f.status | (L.ST_STROKE_LIMIT if mask else 0))
        return seq, dan, depth_mm, speed_mm_s, wire


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    ws = WebStation(tmp_path_factory.mktemp("station"), hoists=1, wind=SHORT_WIND, wind_class=PistonWind)
    try:
        ws.start()
        yield ws
    finally:
        ws.stop()


#: Each rope's cylinder as drawn: the piston's x, the margins, the position text, near or not.
READ_JS = """
return Array.from(document.querySelectorAll('#node-1 tr.rope')).map((row) => {
  const svg = row.querySelector('svg.cyl');
  const a = (sel, name) => parseFloat(svg.querySelector(sel).getAttribute(name));
  return {rope: row.dataset.rope, shown: svg.getBoundingClientRect().width > 0,
          piston: a('.cyl-piston', 'x') + a('.cyl-piston', 'width') / 2,
          marginLo: a('.cyl-margin.lo', 'width'), marginHi: a('.cyl-margin.hi', 'x'),
          stopLo: a('.cyl-stop.lo', 'x') + a('.cyl-stop.lo', 'width'), stopHi: a('.cyl-stop.hi', 'x'),
          near: svg.dataset.near, text: row.querySelector('[data-field="pos"]').textContent};
});
"""


def px(pos_mm: float) -> float:
    """Where the page must draw a piston at `pos_mm` from mid-stroke."""
    return X0 + (pos_mm + STROKE_MM / 2) / STROKE_MM * W


def test_each_cylinder_is_drawn_and_the_piston_moves_with_the_position(browser, station):
    browser.get(f"{station.url}/hoist/{HOIST}")
    wait_for(browser, '#conn[data-state="live"]', 10)
    wait_for(browser, '#node-1 tr.rope[data-rope="4"] svg.cyl[data-pos="-0.5"]', 10)
    cyl = browser.execute_script(READ_JS)
    assert [c["text"] for c in cyl] == ["+1.2 mm", "-3.5 mm", "+8.0 mm", "-0.5 mm"]
    for c, pos in zip(cyl, (1.2, -3.5, 8.0, -0.5)):
        assert c["shown"] and c["near"] == "false"
        assert c["piston"] == pytest.approx(px(pos), abs=0.01)
        assert c["stopLo"] == pytest.approx(X0) and c["stopHi"] == pytest.approx(X0 + W)   # the end stops
        assert c["marginLo"] == pytest.approx(MARGIN_MM / STROKE_MM * W, abs=0.01)           # the margins
        assert c["marginHi"] == pytest.approx(X0 + W - MARGIN_MM / STROKE_MM * W, abs=0.01)
    before = cyl[1]["piston"]
    wind = station.rigs[HOIST].wind
    wind.set_position(1, 440)                  # rope 2 pulled out to +44 mm: into the extended end's margin
    wait_for(browser, '#node-1 tr.rope[data-rope="2"] svg.cyl[data-pos="44"]', 3)
    cyl = browser.execute_script(READ_JS)
    assert cyl[1]["piston"] == pytest.approx(px(44.0), abs=0.01) and cyl[1]["piston"] > before + 80
    assert cyl[1]["near"] == "true" and cyl[1]["text"] == "+44.0 mm"
    assert [c["near"] for c in cyl] == ["false", "true", "false", "false"]
    save_screenshot(browser, "live-pistons")
    wind.set_position(1, -200)                 # and back in, to -20 mm
    wait_for(browser, '#node-1 tr.rope[data-rope="2"] svg.cyl[data-pos="-20"][data-near="false"]', 3)
    assert browser.execute_script(READ_JS)[1]["piston"] == pytest.approx(px(-20.0), abs=0.01)


def test_a_piston_in_its_margin_raises_stroke_limit_in_the_alarm_list(browser, station):
    wind = station.rigs[HOIST].wind
    browser.get(f"{station.url}/hoist/{HOIST}")
    wait_for(browser, '#conn[data-state="live"]', 10)
    wind.set_position(2, -470)                 # rope 3 against its retracted end
    try:
        row = '#alarm-rows tr[data-alarm-id="stroke_limit:n1:r2"]'
        wait_for(browser, row, 3)
        text = browser.find_element(By.CSS_SELECTOR, row).text
        assert "rope 3" in text and "NEW" in text
        wait_for(browser, '#node-1 tr.rope[data-rope="3"] svg.cyl[data-near="true"]', 2)
        save_screenshot(browser, "live-stroke-limit")
    finally:
        wind.set_position(2, 80)


def test_the_hoist_status_is_shown_as_status(browser, station):
    browser.get(f"{station.url}/hoist/{HOIST}")
    el = '#node-1 [data-field="hoist-status"]:not([hidden])'
    wait_for(browser, el, 10)
    text = browser.find_element(By.CSS_SELECTOR, el).text
    assert text.startswith("hoist: ") and len(text) > 12
    rows = browser.find_elements(By.CSS_SELECTOR, "#alarm-rows tr[data-alarm-id]")
    assert not any(r.get_attribute("data-alarm-id").startswith("deviation_possible") for r in rows)
