"""The browser itself: Debian's chromium and chromedriver start headless and render a page."""
from __future__ import annotations

import http.server
import threading
import time
from functools import partial

from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

from web_rig import save_screenshot

PAGE = b"""<!doctype html><html><head><meta charset="utf-8"><title>ropemon smoke</title></head>
<body style="font-family: sans-serif">
<h1 id="title">ropemon</h1><p>rope 1: <span id="t1" data-seq="0">-</span> kN</p>
<script>
let seq = 0;
setInterval(() => { seq += 1; const e = document.getElementById('t1');
  e.textContent = (46.4 + seq / 10).toFixed(1); e.dataset.seq = String(seq); }, 20);
</script></body></html>"""


class _Handler(http.server.BaseHTTPRequestHandler):
    def do_GET(self):
        self.send_response(200)
        self.send_header("Content-Type", "text/html; charset=utf-8")
        self.send_header("Content-Length", str(len(PAGE)))
        self.end_headers()
        self.wfile.write(PAGE)

    def log_message(self, *args):
        pass


def test_chromium_renders_a_local_page_and_runs_its_script(browser):
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        t0 = time.monotonic()
        browser.get(f"http://127.0.0.1:{server.server_port}/")
        assert browser.title == "ropemon smoke"
        WebDriverWait(browser, 5).until(lambda d: int(d.find_element(By.ID, "t1").get_attribute("data-seq")) >= 5)
        text = browser.find_element(By.ID, "t1").text
        assert float(text) > 46.4
        assert time.monotonic() - t0 < 10
        save_screenshot(browser, "smoke")
    finally:
        server.shutdown()
        server.server_close()
