"""End-to-end: a recording served on loopback renders in headless Chromium.

RERUN_NOTES.md §7: the web viewer is served by the rerun CLI on 127.0.0.1;
Debian's chromium is driven through the DevTools websocket (websocket-client),
given ~40 s to load the viewer (WebGL2 on SwiftShader), then screenshotted.
The screenshot must not be blank: it must hold many distinct colours (the JPEG
images) and the colour of the fabricated object seen in the source views.
Takes about a minute; skipped when /usr/bin/chromium is missing.
"""

from __future__ import annotations

import base64
import json
import os
import socket
import subprocess
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = "/usr/bin/chromium"

rr = pytest.importorskip("rerun")
websocket = pytest.importorskip("websocket", reason="pip install websocket-client")
if not Path(CHROMIUM).exists():
    pytest.skip(f"{CHROMIUM} is missing (apt-get install chromium)", allow_module_level=True)

from test_viewer_fixtures import fabricate_run  # noqa: E402

from viewer import RerunSink, serve  # noqa: E402

OBJECT_RGB = np.array([20, 60, 230])  # the fabricated object in the sources (BGR 230,60,20)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_http(url: str, timeout: float) -> bytes:
    deadline = time.time() + timeout
    while time.time() < deadline:
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                return r.read()
        except OSError:
            time.sleep(0.3)
    raise TimeoutError(f"{url} did not answer within {timeout} s")


class _DevTools:
    """Minimal Chrome DevTools Protocol client over one page's websocket."""

    def __init__(self, ws_url: str) -> None:
        self.ws = websocket.create_connection(ws_url, timeout=60, suppress_origin=True)
        self.next_id = 0

    def call(self, method: str, **params):
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv())
            if msg.get("id") == self.next_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    def screenshot(self) -> np.ndarray:
        import cv2

        data = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)

    def close(self) -> None:
        self.ws.close()


def _looks_rendered(shot: np.ndarray) -> tuple[bool, int, int]:
    rgb = shot[..., ::-1].reshape(-1, 3).astype(np.int32)
    n_colors = len(np.unique(rgb[:, 0] << 16 | rgb[:, 1] << 8 | rgb[:, 2]))
    n_object = int((np.abs(rgb - OBJECT_RGB).max(axis=1) < 45).sum())
    return n_colors > 3000 and n_object > 30, n_colors, n_object


def test_web_viewer_renders_recording(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    env = {**os.environ, "HOME": str(home), "XDG_CONFIG_HOME": str(home / ".config"),
           "XDG_DATA_HOME": str(home / ".local/share"), "XDG_CACHE_HOME": str(home / ".cache")}
    subprocess.run([serve.rerun_binary(), "analytics", "disable"], env=env,
                   capture_output=True, timeout=60)
    path = tmp_path / "browser.rrd"
    fabricate_run([RerunSink(path, record_every_rows=8)], H=120, W=160, S=3, n_scans=2,
                  rows_per_chunk=8, sample_every=61)

    port, web_port = _free_port(), _free_port()
    viewer = serve.view(path, web=True, port=port, web_port=web_port, wait=False, env=env,
                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    profile = tmp_path / "chromium-profile"
    browser = None
    try:
        _wait_http(f"http://127.0.0.1:{web_port}/", 30)
        browser = subprocess.Popen(
            [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
             "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update",
             "--disable-sync", f"--user-data-dir={profile}",
             "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1",
             "--window-size=1600,900", "--remote-debugging-address=127.0.0.1",
             "--remote-debugging-port=0", "about:blank"],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True)
        port_file = profile / "DevToolsActivePort"
        deadline = time.time() + 30
        while not (port_file.exists() and port_file.read_text().strip()):
            assert time.time() < deadline, "chromium did not open its DevTools port"
            time.sleep(0.2)
        dbg_port = int(port_file.read_text().split()[0])
        targets = json.loads(_wait_http(f"http://127.0.0.1:{dbg_port}/json/list", 30))
        page = next(t for t in targets if t.get("type") == "page")
        cdp = _DevTools(page["webSocketDebuggerUrl"])
        cdp.call("Page.enable")
        cdp.call("Page.navigate", url=serve.web_url(port=port, web_port=web_port))
        time.sleep(30)
        ok, n_colors, n_object = False, 0, 0
        for _ in range(8):  # ~40 s usually suffice; allow up to ~70 s
            shot = cdp.screenshot()
            ok, n_colors, n_object = _looks_rendered(shot)
            if ok:
                break
            time.sleep(5)
        import cv2

        cv2.imwrite(str(tmp_path / "screenshot.png"), shot)
        if os.environ.get("DYNREMOVE_SCREENSHOT_DIR"):
            cv2.imwrite(os.path.join(os.environ["DYNREMOVE_SCREENSHOT_DIR"],
                                     "viewer_screenshot.png"), shot)
        cdp.close()
        assert shot.shape[1] == 1600 and shot.shape[0] > 600
        assert ok, (f"viewer looks blank: {n_colors} distinct colours, {n_object} object "
                    f"pixels (see {tmp_path / 'screenshot.png'})")
    finally:
        if browser is not None and browser.poll() is None:
            os.killpg(browser.pid, 15)
            try:
                browser.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(browser.pid, 9)
        serve.stop(viewer)
