"""Screenshots of .rrd recordings in rerun's web viewer, rendered by headless Chromium.

    python scripts/rrd_screenshots.py OUT_DIR [--write] [--only KIND,...] [--png-dir docs/img/rrd]

With ``--write`` it first writes one small recording of every type (``scripts/rrd_examples.py``)
into OUT_DIR; then, per recording, it serves the file with ``rerun --serve-web`` (the web viewer
of the installed rerun-sdk), opens the viewer in headless Chromium (``&renderer=webgl``: software
GL through SwiftShader), waits until the page has drawn, and saves ``<png-dir>/<kind>.png`` (the
viewer at 1600 x 1000, scaled and palette-reduced to stay under 300 kB).

Needs ``chromium`` on the PATH (Debian: ``apt-get install chromium``). Chromium is driven through
its DevTools protocol with the ``websockets`` package; nothing else is required.
"""
from __future__ import annotations

import argparse
import asyncio
import base64
import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import websockets
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))
import rrd_examples  # noqa: E402  (the sibling script: writes the recordings)

WIDTH, HEIGHT = 1600, 1000
MAX_BYTES = 300_000


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for(cond, timeout_s: float, what: str):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        v = cond()
        if v:
            return v
        time.sleep(0.2)
    raise RuntimeError(f"timed out after {timeout_s:.0f} s waiting for {what}")


def _serve(rrd: Path, log):
    """Start ``rerun --serve-web`` on free ports; returns (process, viewer URL)."""
    web, grpc = _free_port(), _free_port()
    rerun = Path(sys.executable).with_name("rerun")
    proc = subprocess.Popen([str(rerun), "--serve-web", "--web-viewer-port", str(web), "--port", str(grpc),
                             str(rrd)], stdout=log, stderr=subprocess.STDOUT, start_new_session=True)

    def up():
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=1).read(1)
            return True
        except OSError:
            return False

    _wait_for(up, 30, "the rerun web viewer")
    url = (f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy"
           "&renderer=webgl")
    return proc, url


def _chromium(log, profile: Path):
    """Start headless Chromium with its DevTools port; returns (process, websocket URL of a page)."""
    exe = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if exe is None:
        raise SystemExit("no chromium on the PATH: apt-get install chromium (Debian) and run again")
    port = _free_port()
    proc = subprocess.Popen([exe, "--headless=new", "--no-sandbox", "--use-angle=swiftshader",
                             "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--hide-scrollbars",
                             f"--window-size={WIDTH},{HEIGHT}", f"--remote-debugging-port={port}",
                             f"--user-data-dir={profile}", "about:blank"], stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)

    def page():
        try:
            tabs = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=1).read())
        except OSError:
            return None
        return next((t["webSocketDebuggerUrl"] for t in tabs if t.get("type") == "page"), None)

    return proc, _wait_for(page, 30, "chromium's DevTools port")


async def _shoot(ws_url: str, url: str, settle_s: float, timeout_s: float) -> bytes:
    """Open ``url``; take screenshots every 2 s until two in a row agree (the viewer has loaded
    and drawn) after at least ``settle_s``; returns the last PNG."""
    async with websockets.connect(ws_url, max_size=64 * 2**20) as ws:
        n = 0

        async def call(method, **params):
            nonlocal n
            n += 1
            await ws.send(json.dumps({"id": n, "method": method, "params": params}))
            while True:
                msg = json.loads(await ws.recv())
                if msg.get("id") == n:
                    if "error" in msg:
                        raise RuntimeError(f"{method}: {msg['error']}")
                    return msg["result"]

        await call("Emulation.setDeviceMetricsOverride", width=WIDTH, height=HEIGHT, deviceScaleFactor=1,
                   mobile=False)
        await call("Page.navigate", url=url)
        t0, last, png = time.monotonic(), None, b""
        while time.monotonic() - t0 < timeout_s:
            await asyncio.sleep(2.0)
            png = base64.b64decode((await call("Page.captureScreenshot", format="png"))["data"])
            if time.monotonic() - t0 >= settle_s and png == last:
                break
            last = png
        return png


def _small_png(png: bytes, out: Path) -> int:
    """Save ``png`` scaled to 1200 px wide, palette-reduced until under MAX_BYTES; returns bytes."""
    img = Image.open(io.BytesIO(png)).convert("RGB")
    img = img.resize((1200, round(img.height * 1200 / img.width)), Image.LANCZOS)
    for colors in (256, 128, 64):
        buf = io.BytesIO()
        img.quantize(colors=colors, method=Image.Quantize.MEDIANCUT).save(buf, format="PNG", optimize=True)
        if buf.tell() < MAX_BYTES:
            break
    out.write_bytes(buf.getvalue())
    return buf.tell()


def _stop(p: subprocess.Popen) -> None:
    for sig, wait in ((signal.SIGTERM, 10), (signal.SIGKILL, 5)):
        try:
            os.killpg(p.pid, sig)
        except ProcessLookupError:
            return
        try:
            p.wait(wait)
            return
        except subprocess.TimeoutExpired:
            continue


def screenshot(rrd: Path, out: Path, settle_s: float = 20.0, timeout_s: float = 90.0) -> int:
    """Render ``rrd`` in the web viewer and save the PNG ``out``; returns its size in bytes."""
    with tempfile.TemporaryDirectory(prefix="rrdshot.") as tmp:
        log = open(Path(tmp) / "log.txt", "w")
        server = browser = None
        try:
            server, url = _serve(rrd, log)
            browser, ws_url = _chromium(log, Path(tmp) / "profile")
            png = asyncio.run(_shoot(ws_url, url, settle_s, timeout_s))
            return _small_png(png, out)
        finally:
            for p in (browser, server):  # each in a session of its own: end its whole process group
                if p is not None:
                    _stop(p)
            log.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", type=Path, help="folder of the recordings (OUT_DIR/<kind>/...)")
    ap.add_argument("--write", action="store_true", help="write the recordings first (rrd_examples.py)")
    ap.add_argument("--only", default=",".join(rrd_examples.KINDS), help="comma-separated kinds")
    ap.add_argument("--png-dir", type=Path, default=Path("docs/img/rrd"), help="where the PNGs go")
    ap.add_argument("--settle", type=float, default=20.0, help="least seconds before the page counts as drawn")
    a = ap.parse_args(argv)
    kinds = [k for k in a.only.split(",") if k]
    if a.write:
        rrds = rrd_examples.write(a.out_dir, kinds)
    else:
        rrds = {k: a.out_dir / k / rrd_examples.KINDS[k][1] for k in kinds}
    missing = [str(p) for p in rrds.values() if not p.is_file()]
    if missing:
        raise SystemExit(f"no recording at {', '.join(missing)}: write them first (--write)")
    a.png_dir.mkdir(parents=True, exist_ok=True)
    for kind, rrd in rrds.items():
        size = screenshot(rrd, a.png_dir / f"{kind}.png", settle_s=a.settle)
        print(f"{a.png_dir / f'{kind}.png'}: {size / 1000:.0f} kB", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
