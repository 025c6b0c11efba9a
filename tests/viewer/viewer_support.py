"""Helpers of the viewer tests: graphs with a visualizer, page probes, a bus tap, artefacts, pixels."""
from __future__ import annotations

import base64
import json
import shutil
import socket
import time
import urllib.request
from pathlib import Path
from typing import Any, Callable

try:
    from playwright.sync_api import TimeoutError as PlaywrightTimeout
except ImportError:   # the browser tests skip (conftest); the socket-level helpers here still serve
    PlaywrightTimeout = TimeoutError

from browser_support import CHROMIUM, CHROMIUM_ARGS  # noqa: E402,F401 - the viewer tests' names

REPO_ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO_ROOT / "artifacts"
TESTING = "mocapgraph.testing.viewer_nodes"

# Connection failures while a graph is down are logged by the browser itself, not by the page.
BENIGN_CONSOLE = ("WebSocket connection to", "ERR_CONNECTION_REFUSED", "GPU stall due to ReadPixels")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stage_graph(port: int, gym_s: float = 0.3, rate_hz: float = 120.0) -> str:
    """A graph with every drawn type, two actors, a command echo per channel and an unknown type."""
    return f"""
nodes:
  - name: alice
    type: {TESTING}:StagePerformer
    params: {{actor: alice, rate_hz: {rate_hz}, publish: [markers, actor, skeleton, physics], nan_joint: 6}}
  - name: bob
    type: {TESTING}:StagePerformer
    params: {{actor: bob, rate_hz: {rate_hz}, publish: [actor], center: [0.4, -0.6], radius: 2.0, phase: 2.0}}
  - name: carol
    type: {TESTING}:StagePerformer
    params: {{actor: carol, rate_hz: 60.0, publish: [character], center: [-1.0, 1.0], radius: 0.8, phase: 4.0}}
  - name: truth
    type: {TESTING}:StagePerformer
    params: {{actor: truth, rate_hz: 60.0, publish: [actor], center: [0.4, -0.6], radius: 2.0, phase: 2.0}}
    remap: {{actor_pose: ground_truth, skeleton_model: truth_model}}
  - name: calib
    type: {TESTING}:CommandEcho
    params: {{role: calibration, gym_s: {gym_s}}}
  - name: player
    type: {TESTING}:CommandEcho
    params: {{role: player, duration_s: 20.0}}
  - name: plates
    type: {TESTING}:ForcePlateSource
  - name: viz
    type: visualizer
    params: {{port: {port}, extra_topics: [force_plates, ground_truth], message_modules: [{TESTING}]}}
"""


def real_calibration_graph(port: int, calibration_params: str = "auto: false, gym_seconds: 1.0",
                           extra_nodes: str = "") -> str:
    """The looping synthetic actor, the real calibration node (``calibration_params``, YAML flow
    mapping body), any ``extra_nodes`` (YAML list items) and the viewer on ``port``."""
    return f"""
nodes:
  - name: actor
    type: synthetic_actor
    params: {{rate_hz: 120.0, loop: true}}
    remap: {{markers: actor_markers, marker_layout: actor_layout}}
  - name: calibration
    type: calibration
    params: {{{calibration_params}}}
    remap: {{markers: actor_markers, marker_layout: actor_layout}}
{extra_nodes}  - name: viz
    type: visualizer
    params: {{port: {port}}}
"""


def viewer_url(graph, timeout: float = 20.0) -> str:
    """The page URL the viewer printed (with its access token), as a user would copy it."""
    import re

    line = graph.wait_for("viewer at ", timeout)
    return re.search(r"viewer at (\S+)", line).group(1)


def ws_url(url: str) -> str:
    """The WebSocket address of a viewer page URL (token kept), as the page builds it."""
    base, _, query = url.partition("?")
    return base.replace("http://", "ws://").rstrip("/") + "/ws?" + query


def viewer_stats(url: str) -> dict[str, Any]:
    """The server's own counters (/stats, token of the page URL): connections and bundles sent to each."""
    base, _, query = url.partition("?")
    with urllib.request.urlopen(base.rstrip("/") + "/stats?" + query, timeout=5) as r:
        return json.loads(r.read())


def wait_until(check: Callable[[], Any], timeout: float = 10.0, what: str = "condition") -> Any:
    t_end = time.monotonic() + timeout
    last = None
    while time.monotonic() < t_end:
        last = check()
        if last:
            return last
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what} (last: {last!r})")


class PageProbe:
    """A viewer page with its console errors collected."""

    def __init__(self, page) -> None:
        self.page = page
        self.console: list[tuple[str, str]] = []
        page.on("console", lambda m: self.console.append((m.type, m.text)))
        page.on("pageerror", lambda e: self.console.append(("pageerror", str(e))))

    def errors(self) -> list[str]:
        return [t for kind, t in self.console if kind in ("error", "pageerror") and not any(b in t for b in BENIGN_CONSOLE)]

    def stats(self) -> dict[str, Any]:
        return self.page.evaluate("() => JSON.parse(JSON.stringify(window.mocapgraphStats || null))")

    def wait(self, js: str, timeout: float = 10.0) -> Any:
        """Wait for a JS expression over ``s`` (the stats object) to be truthy; returns its value."""
        try:
            self.page.wait_for_function(f"() => {{ const s = window.mocapgraphStats; return s && ({js}); }}",
                                        timeout=timeout * 1000)
        except PlaywrightTimeout:   # say what the page showed, not only that it timed out
            s = self.stats() or {}
            shown = {k: s.get(k) for k in ("connected", "connects", "framesDrawn", "fps", "stalled", "bundles", "records")}
            raise AssertionError(f"page: not ({js}) within {timeout} s; the page showed {shown}") from None
        return self.page.evaluate(f"() => {{ const s = window.mocapgraphStats; return ({js}); }}")


def save_artifact(src: Path, name: str) -> Path:
    """Copy a test artefact to artifacts/ at the repository root (gitignored)."""
    ARTIFACTS.mkdir(exist_ok=True)
    dst = ARTIFACTS / name
    shutil.copyfile(src, dst)
    return dst


def image_stats(page, png: bytes) -> dict[str, Any]:
    """Decode a PNG with the browser's image decoder (not WebGL) and measure its pixels."""
    return page.evaluate("""async (b64) => {
        const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
        const bmp = await createImageBitmap(new Blob([bytes], {type: "image/png"}));
        const c = new OffscreenCanvas(bmp.width, bmp.height);
        const g = c.getContext("2d");
        g.drawImage(bmp, 0, 0);
        const d = g.getImageData(0, 0, bmp.width, bmp.height).data;
        let sum = 0, sum2 = 0, green = 0, red = 0;
        const colours = new Set();
        for (let i = 0; i < d.length; i += 4) {
            const r = d[i], gg = d[i + 1], b = d[i + 2];
            const y = (r + gg + b) / 3;
            sum += y; sum2 += y * y;
            if (gg > 150 && gg > r + 50 && gg > b + 40) green++;
            if (r > 170 && r > gg + 80 && r > b + 80) red++;
            colours.add((r >> 4) << 8 | (gg >> 4) << 4 | (b >> 4));
        }
        const n = d.length / 4, mean = sum / n;
        return {width: bmp.width, height: bmp.height, mean, std: Math.sqrt(sum2 / n - mean * mean), green, red,
                colours: colours.size};
    }""", base64.b64encode(png).decode())


class BusTap:
    """Collects every message of some topics of a running graph (an independent subscriber)."""

    def __init__(self, master: str, topics: list[str]) -> None:
        import threading

        from mocapgraph.bus.manifest import fetch_manifest, subscribe

        self.sock = subscribe(fetch_manifest(master), topics)
        self.messages: list[tuple[Any, Any]] = []
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from mocapgraph.messages import decode

        while not self._stop:
            if self.sock.poll(50):
                env, msg = decode(self.sock.recv_multipart())
                self.messages.append((env, msg))

    def of(self, topic: str) -> list[tuple[Any, Any]]:
        return [(e, m) for e, m in list(self.messages) if e.topic == topic]

    def close(self) -> None:
        self._stop = True
        self._thread.join(2)
        self.sock.close(0)


def run_async(coro_factory: Callable[[], Any]) -> Any:
    """Run a coroutine in a thread of its own (Playwright's sync API holds this thread's event loop)."""
    import asyncio
    import threading

    box: dict[str, Any] = {}

    def target() -> None:
        try:
            box["value"] = asyncio.run(coro_factory())
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller
            box["error"] = exc

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(60)
    if "error" in box:
        raise box["error"]
    return box.get("value")
