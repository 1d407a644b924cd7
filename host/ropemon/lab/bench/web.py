"""`ropemon bench web`: one station, 8 hoists at 10 frames/s each, 20 open browsers.

The station is `ropemon serve` (a subprocess) with its [web] face, each hoist's receiver a pty
the bench writes its node's frames into (`ropemon.lab.webstation`): receivers, decode, MAC,
merge, alarms, each hoist's log and the web face all run, as in a hoist room. Its 20 clients:
`BROWSERS` real pages (headless chromium, one window each, on different hoists' live pages) and
the rest plain SSE readers of the hoists' live streams (another process), spread over the
hoists.

Latency: from a frame's arrival at the station (the moment the bench has written it into the
receiver's pty, `time.time()`) to its value in the page's DOM (a MutationObserver on the live
page's rope cells takes `performance.timeOrigin + performance.now()` when they change; the same
clock). Each frame carries its seq modulo 100 in the tenths of a kN of ropes 1 and 2 (the page
shows one decimal), so every value in the DOM names the frame it came from.

CPU: the station process's user + system time (/proc/PID/stat, every thread) over the
measured window, as a share of one core.

Baseline, in the same run, alternating with the station: the same frames through a bare
Starlette SSE endpoint on the same uvicorn with no station work (`webbase`: split, COBS, seq and
tensions, JSON, broadcast) to the same pages and readers. A third variant runs the station at
tick_hz 20 (the station file's default is 4: the station hands queued frames to its listeners
once per tick).
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from ropemon.lab.webstation import Wind, WebStation

HOISTS = 8
FRAME_HZ = 10.0
CLIENTS = 20
BROWSERS = 4
TARGET_P99_S = 0.25
TARGET_CPU = 0.25

#: Installed once the live page's node panel is there: records (time, rope 1 text, rope 2 text,
#: the panel's data-t) at every change of the first two ropes' cells.
OBSERVE_JS = """
window.__lat = [];
const panel = document.getElementById('node-1');
const cells = Array.from(panel.querySelectorAll('tr.rope [data-field="comp"]')).slice(0, 2);
let last = '';
new MutationObserver(() => {
  const a = cells[0].textContent, b = cells[1].textContent;
  if (a + '|' + b === last) return;
  last = a + '|' + b;
  window.__lat.push([performance.timeOrigin + performance.now(), a, b, parseFloat(panel.dataset.t)]);
}).observe(panel, {subtree: true, childList: true, characterData: true});
"""
TAKE_JS = "const r = window.__lat; window.__lat = []; return r;"


class CodedWind(Wind):
    """The wind, with each frame's seq modulo 100 in ropes 1 and 2's tenths of a kN."""

    def adjust(self, seq: int, dan: list[int]) -> list[int]:
        code = seq % 100
        dan = list(dan)
        dan[0] = dan[0] // 100 * 100 + (code % 10) * 10
        dan[1] = dan[1] // 100 * 100 + (code // 10) * 10
        return dan


def _code(a: str, b: str) -> int | None:
    try:
        return int(b.split(".")[1][0]) * 10 + int(a.split(".")[1][0])
    except (IndexError, ValueError):
        return None


def _percentile(xs: list[float], q: float) -> float:
    if not xs:
        return float("nan")
    xs = sorted(xs)
    k = min(len(xs) - 1, max(0, int(round(q * (len(xs) - 1)))))
    return xs[k]


def _baseline_server(ws: WebStation) -> list[str]:
    return [sys.executable, "-m", "ropemon.lab.bench.webbase", "server", str(ws.port),
            *[f"{hid}={rig.port.port}" for hid, rig in ws.rigs.items()]]  # type: ignore[attr-defined]


class _Readers:
    """The SSE readers' process and its latest report (time, events read by each so far)."""

    def __init__(self, cmd: list[str]) -> None:
        import threading

        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
        self.latest: tuple[float, list[int]] | None = None
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            d = json.loads(line)
            self.latest = (d["t"], d["events"])

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def _browsers(n: int) -> list[Any]:
    """`n` windows of one headless chromium (Debian's, through /usr/bin/chromedriver)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="ropemon-bench-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-dev-shm-usage", "--disable-extensions", "--mute-audio",
                 "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
                 "--disable-backgrounding-occluded-windows", "--window-size=1280,900",
                 f"--user-data-dir={profile}"):
        opts.add_argument(flag)
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=opts)
    driver._ropemon_profile = profile  # type: ignore[attr-defined]
    handles = [driver.current_window_handle]
    for _ in range(n - 1):
        driver.switch_to.new_window("window")
        handles.append(driver.current_window_handle)
    return [driver, handles]


def _wait(driver: Any, css: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not driver.execute_script("return !!document.querySelector(arguments[0]);", css):
        if time.monotonic() > deadline:
            raise RuntimeError(f"{driver.current_url}: no {css!r} after {timeout_s} s")
        time.sleep(0.1)


def one_run(variant: str, seconds: float, browser: list[Any], warmup_s: float = 3.0) -> dict:
    """One measured window of `variant` ("station", "station-tick20", "baseline")."""
    driver, handles = browser
    with tempfile.TemporaryDirectory(prefix="ropemon-bench-web-") as d:
        ws = WebStation(Path(d), hoists=HOISTS, frame_hz=FRAME_HZ, wind_class=CodedWind,
                        tick_hz=20.0 if variant == "station-tick20" else None,
                        server=_baseline_server if variant == "baseline" else None)
        clients: _Readers | None = None
        try:
            ws.start()
            ids = list(ws.rigs)
            watched = ids[:BROWSERS]
            n_sse = CLIENTS - BROWSERS
            sse_hoists = ids[BROWSERS:] + ids[:BROWSERS]            # the readers start on the other hoists
            clients = _Readers([sys.executable, "-m", "ropemon.lab.bench.webbase", "clients", ws.url, str(n_sse),
                                str(warmup_s + seconds + 60), *sse_hoists])
            for h, hid in zip(handles, watched):
                driver.switch_to.window(h)
                driver.get(f"{ws.url}/hoist/{hid}")
                _wait(driver, '#node-1 tr.rope[data-rope="2"] [data-field="comp"]', 15)
                driver.execute_script(OBSERVE_JS)
            time.sleep(warmup_s)
            for h in handles:
                driver.switch_to.window(h)
                driver.execute_script(TAKE_JS)
            sse0 = clients.latest
            cpu0, wall0, load0 = ws.cpu_s(), time.monotonic(), os.getloadavg()[0]
            t_from = time.time()
            time.sleep(seconds)
            cpu1, wall1 = ws.cpu_s(), time.monotonic()
            t_to = time.time()
            sse1 = clients.latest
            records = {}
            for h, hid in zip(handles, watched):
                driver.switch_to.window(h)
                records[hid] = driver.execute_script(TAKE_JS)
            load1 = os.getloadavg()[0]
            lat, station_part, web_part, unmatched, shown = [], [], [], 0, 0
            fed = 0
            for hid in watched:
                sent = ws.sent(hid)
                fed += sum(1 for s in sent.values() if t_from <= s.t <= t_to - 1.0)
                by_code: dict[int, list] = {}
                for s in sent.values():
                    by_code.setdefault(s.seq % 100, []).append(s)
                for t_ms, a, b, st in records[hid]:
                    code = _code(a, b)
                    t_dom = t_ms / 1000.0
                    cands = [s for s in by_code.get(code, []) if s.t <= t_dom] if code is not None else []
                    if not cands:
                        unmatched += 1
                        continue
                    s = max(cands, key=lambda s: s.t)
                    if t_dom - s.t > 5.0:
                        unmatched += 1
                        continue
                    if s.t < t_from or s.t > t_to - 1.0:
                        continue
                    shown += 1
                    lat.append(t_dom - s.t)
                    if st == st:    # not NaN: the listener's (the baseline's decoder's) time of the frame
                        station_part.append(st - s.t)
                        web_part.append(t_dom - st)
        finally:
            if clients is not None:
                clients.stop()
            ws.stop()
    return {
        "variant": variant, "seconds": round(wall1 - wall0, 2),
        "cpu_core_frac": round((cpu1 - cpu0) / (wall1 - wall0), 4),
        "frames_fed_watched": fed, "frames_shown": shown, "unmatched": unmatched,
        "p50_s": round(_percentile(lat, 0.50), 4), "p99_s": round(_percentile(lat, 0.99), 4),
        "max_s": round(max(lat), 4) if lat else None,
        "to_listener_p50_s": round(_percentile(station_part, 0.50), 4) if station_part else None,
        "to_listener_p99_s": round(_percentile(station_part, 0.99), 4) if station_part else None,
        "listener_to_dom_p50_s": round(_percentile(web_part, 0.50), 4) if web_part else None,
        "listener_to_dom_p99_s": round(_percentile(web_part, 0.99), 4) if web_part else None,
        "load_avg": [round(load0, 2), round(load1, 2)],
        # events per second each SSE reader got in the window (frames of its hoist, alarms, status)
        "sse_events_per_s": sorted(round((b - a) / (sse1[0] - sse0[0]), 1) for a, b in zip(sse0[1], sse1[1]))
        if sse0 and sse1 and sse1[0] > sse0[0] else None,
    }


def measure(quick: bool = False) -> dict:
    repeats, seconds = (1, 8.0) if quick else (3, 20.0)
    variants = ("station", "baseline") if quick else ("station", "baseline", "station-tick20")
    browser = _browsers(BROWSERS)
    runs: list[dict] = []
    try:
        for _ in range(repeats):
            for v in variants:
                runs.append(one_run(v, seconds, browser))
    finally:
        import shutil
        browser[0].quit()
        shutil.rmtree(getattr(browser[0], "_ropemon_profile", ""), ignore_errors=True)
    out: dict[str, Any] = {"hoists": HOISTS, "frame_hz": FRAME_HZ, "clients": CLIENTS, "browsers": BROWSERS,
                           "repeats": repeats, "seconds": seconds, "runs": runs,
                           "time_utc": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    for v in variants:
        rs = [r for r in runs if r["variant"] == v]
        out[v] = {k: round(statistics.median(r[k] for r in rs), 4)
                  for k in ("cpu_core_frac", "p50_s", "p99_s", "max_s")
                  if all(r[k] is not None for r in rs)}
        out[v]["frames_shown"] = sum(r["frames_shown"] for r in rs)
        out[v]["frames_fed_watched"] = sum(r["frames_fed_watched"] for r in rs)
        for k in ("to_listener_p99_s", "listener_to_dom_p50_s", "listener_to_dom_p99_s"):
            xs = [r[k] for r in rs if r[k] is not None]
            if xs:
                out[v][k] = round(statistics.median(xs), 4)
    s, b = out["station"], out["baseline"]
    out["p99_vs_baseline"] = round(s["p99_s"] / b["p99_s"], 2) if b.get("p99_s") else None
    out["cpu_vs_baseline"] = round(s["cpu_core_frac"] / b["cpu_core_frac"], 2) if b.get("cpu_core_frac") else None
    out["p99_met"] = s["p99_s"] <= TARGET_P99_S
    out["cpu_met"] = s["cpu_core_frac"] <= TARGET_CPU
    return out


def describe(f: dict) -> str:
    def row(name: str, v: dict) -> str:
        return (f"  {name:<30} p50 {v['p50_s'] * 1000:6.0f} ms  p99 {v['p99_s'] * 1000:6.0f} ms  "
                f"max {v.get('max_s', float('nan')) * 1000:6.0f} ms  CPU {v['cpu_core_frac'] * 100:5.1f} % of a core"
                f"  ({v['frames_shown']:,} of {v['frames_fed_watched']:,} frames timed)")
    lines = [f"web: {f['hoists']} hoists x {f['frame_hz']:g} frames/s, {f['clients']} clients "
             f"({f['browsers']} chromium pages, {f['clients'] - f['browsers']} SSE readers); medians of "
             f"{f['repeats']} x {f['seconds']:g} s, {f['time_utc']}",
             row("station (tick_hz 4)", f["station"])]
    if "station-tick20" in f:
        lines.append(row("station, tick_hz 20", f["station-tick20"]))
    lines.append(row("baseline (bare Starlette SSE)", f["baseline"]))
    s = f["station"]
    rates = [x for r in f["runs"] if r["variant"] == "station" and r["sse_events_per_s"] for x in r["sse_events_per_s"]]
    if rates:
        lines.append(f"  each of the station's {f['clients'] - f['browsers']} SSE readers got {min(rates):.1f} to "
                     f"{max(rates):.1f} events/s (its hoist's 10 frames/s, alarms and status)")
    lines.append(f"  station vs baseline: p99 x{f['p99_vs_baseline']}, CPU x{f['cpu_vs_baseline']}")
    for name, v in (("station (tick_hz 4)", s), ("station, tick_hz 20", f.get("station-tick20"))):
        if v and "to_listener_p99_s" in v and "listener_to_dom_p99_s" in v:
            lines.append(f"  {name}: arrival to the web listener p99 {v['to_listener_p99_s'] * 1000:.0f} ms (the "
                         f"station's pump), listener to the DOM p50 {v['listener_to_dom_p50_s'] * 1000:.0f} ms, "
                         f"p99 {v['listener_to_dom_p99_s'] * 1000:.0f} ms (the web face and the browser)")
    lines.append(f"  targets: p99 <= {TARGET_P99_S * 1000:.0f} ms: {'met' if f['p99_met'] else 'NOT met'}; "
                 f"CPU <= {TARGET_CPU * 100:.0f} % of a core: {'met' if f['cpu_met'] else 'NOT met'}")
    return "\n".join(lines)


if __name__ == "__main__":
    figures = measure(quick="--quick" in sys.argv)
    print(json.dumps(figures) if "--json" in sys.argv else describe(figures))
