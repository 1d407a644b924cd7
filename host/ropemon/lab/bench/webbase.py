"""The web benchmark's baseline and load: a bare Starlette SSE server, and plain SSE clients.

    python -m ropemon.lab.bench.webbase server PORT HOIST=PTY...  the baseline server (a subprocess)
    python -m ropemon.lab.bench.webbase clients URL N SECONDS HOIST...  N plain SSE readers (a subprocess)

The baseline server does what the web face must do at the least, with no station work: one
reader thread per receiver's pty (pyserial, as the station opens its ports) splits the bytes on
0x00, takes each frame's seq and first rope's tension out of the COBS body (no CRC, no MAC,
no merge, no alarms, no log), and every client's stream gets it as one server-sent event,
through the same uvicorn the web face runs. Its page, /hoist/ID, shows the four ropes' tensions
in cells marked as the web face's live page marks them (`#node-1 tr.rope [data-field=comp]`, one
decimal), so the same observer times both.
"""
from __future__ import annotations

import asyncio
import json
import sys
import threading
import time
from urllib.parse import urlsplit

PAGE = """<!doctype html><html><head><meta charset="utf-8"><title>baseline</title></head>
<body data-page="baseline" data-hoist="%(hoist)s"><h1>baseline: %(hoist)s</h1>
<section id="node-1"><table><tbody>
<tr class="rope" data-rope="1"><td data-field="comp"></td></tr><tr class="rope" data-rope="2"><td data-field="comp"></td></tr>
<tr class="rope" data-rope="3"><td data-field="comp"></td></tr><tr class="rope" data-rope="4"><td data-field="comp"></td></tr>
</tbody></table></section>
<script src="/page.js"></script></body></html>"""

#: The page's script (a file of its own, as the web face's: a CSP without inline scripts).
SCRIPT = """
const cells = Array.from(document.querySelectorAll('[data-field="comp"]'));
const es = new EventSource('/hoist/' + document.body.dataset.hoist + '/stream');
es.addEventListener('frame', (e) => {
  const m = JSON.parse(e.data);
  document.getElementById('node-1').dataset.t = m.t;
  m.kN.forEach((x, i) => { if (cells[i].textContent !== x.toFixed(1)) cells[i].textContent = x.toFixed(1); });
});
"""


def server(port: int, receivers: list[str]) -> None:
    """Serve the baseline on `port`; `receivers` are HOIST=PTY pairs."""
    import serial
    import uvicorn
    from cobs import cobs
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import HTMLResponse, Response, StreamingResponse
    from starlette.routing import Route

    from ropemon.station.protocol import DAN_TO_N, HEADER, ROPE

    pairs = [r.split("=", 1) for r in receivers]
    subs: dict[str, set[asyncio.Queue]] = {h: set() for h, _ in pairs}
    loop_box: list[asyncio.AbstractEventLoop] = []

    def broadcast(hoist: str, text: str) -> None:
        for q in list(subs[hoist]):
            try:
                q.put_nowait(text)
            except asyncio.QueueFull:
                subs[hoist].discard(q)

    def reader(hoist: str, path: str) -> None:
        port_ = serial.serial_for_url(path, baudrate=115200, timeout=0.2)
        buf = b""
        while True:
            data = port_.read(port_.in_waiting or 1)
            if not data:
                continue
            buf += data
            *bodies, buf = buf.split(b"\x00")
            for body in bodies:
                if not body:
                    continue
                try:
                    raw = cobs.decode(body)
                    seq = HEADER.unpack_from(raw)[4]
                    n = (len(raw) - HEADER.size) // ROPE.size
                    kn = [round(ROPE.unpack_from(raw, HEADER.size + k * ROPE.size)[0] * DAN_TO_N / 1000, 2)
                          for k in range(min(n, 4))]
                except Exception:
                    continue
                text = "event: frame\ndata: " + json.dumps({"seq": seq, "t": time.time(), "kN": kn}) + "\n\n"
                if loop_box:
                    loop_box[0].call_soon_threadsafe(broadcast, hoist, text)

    async def index(request: Request) -> HTMLResponse:
        return HTMLResponse("baseline")

    async def page(request: Request) -> HTMLResponse:
        return HTMLResponse(PAGE % {"hoist": request.path_params["hoist"]})

    async def script(request: Request) -> Response:
        return Response(SCRIPT, media_type="text/javascript")

    async def events(request: Request) -> StreamingResponse:
        hoist = request.path_params["hoist"]
        if not loop_box:                   # the readers hand frames to this loop once a client is here
            loop_box.append(asyncio.get_running_loop())
        q: asyncio.Queue = asyncio.Queue(600)
        subs[hoist].add(q)

        async def stream():
            try:
                yield "retry: 2000\n\n"
                while True:
                    yield await q.get()
            finally:
                subs[hoist].discard(q)
        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})

    app = Starlette(routes=[Route("/", index), Route("/page.js", script), Route("/hoist/{hoist}", page),
                            Route("/hoist/{hoist}/stream", events)])
    for hoist, path in pairs:
        threading.Thread(target=reader, args=(hoist, path), daemon=True).start()
    uvicorn.run(app, host="127.0.0.1", port=port, log_level="warning", access_log=False, server_header=False,
                lifespan="off")


async def _client(host: str, port: int, path: str, until: float, counts: list[int], i: int,
                  cookie: str | None) -> None:
    while time.monotonic() < until:
        try:
            reader, writer = await asyncio.open_connection(host, port)
        except OSError:
            await asyncio.sleep(0.2)
            continue
        head = f"GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\nAccept: text/event-stream\r\n"
        if cookie:
            head += f"Cookie: {cookie}\r\n"
        writer.write((head + "\r\n").encode())
        await writer.drain()
        try:
            while True:
                left = until - time.monotonic()
                if left <= 0:
                    break
                chunk = await asyncio.wait_for(reader.read(65536), left)
                if not chunk:
                    break
                counts[i] += chunk.count(b"\n\n")
        except (asyncio.TimeoutError, OSError):
            pass
        finally:
            writer.close()


def clients(base: str, n: int, seconds: float, hoists: list[str]) -> None:
    """`n` SSE readers of BASE/hoist/ID/stream (the hoists in turn) for `seconds`; prints a JSON
    line every second: the time and the events each client has read so far."""
    u = urlsplit(base)
    counts = [0] * n

    async def report(until: float) -> None:
        while time.monotonic() < until:
            await asyncio.sleep(1.0)
            print(json.dumps({"t": time.time(), "events": counts}), flush=True)

    async def main() -> None:
        until = time.monotonic() + seconds
        await asyncio.gather(report(until), *(
            _client(u.hostname or "127.0.0.1", u.port or 80, f"/hoist/{hoists[i % len(hoists)]}/stream", until,
                    counts, i, None) for i in range(n)))
    asyncio.run(main())


if __name__ == "__main__":
    if sys.argv[1] == "server":
        server(int(sys.argv[2]), sys.argv[3:])
    elif sys.argv[1] == "clients":
        clients(sys.argv[2], int(sys.argv[3]), float(sys.argv[4]), sys.argv[5:])
    else:
        raise SystemExit(f"usage: {__doc__}")
