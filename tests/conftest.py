"""Shared fixtures: where the real captures live, and skipping cleanly without them."""
from __future__ import annotations

from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = (REPO_ROOT / ".." / "shared" / "data").resolve()

# the synthetic capture (TRC, bag, calibrated model) that the bag, CLI and report tests share
pytest_plugins = ["capture_fixture"]


@pytest.fixture
def shared_data() -> Path:
    """Folder of real captures (../shared/data); the test is skipped when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is absent")
    return SHARED_DATA


# ----- launching real graphs -------------------------------------------------------------------
import os
import signal
import subprocess
import sys
import threading
import time
import uuid


class LaunchedGraph:
    """A `mocapgraph launch` subprocess with its own manifest endpoint and captured output."""

    def __init__(self, graph_file: Path, args: list[str], tmp: Path) -> None:
        self.master = f"ipc://{tmp / ('master-' + uuid.uuid4().hex[:8])}"
        self.env = dict(os.environ, MOCAPGRAPH_MASTER=self.master, PYTHONUNBUFFERED="1")
        self.lines: list[str] = []
        self.line_times: list[float] = []  # monotonic time each line was read, s
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "mocapgraph", "launch", str(graph_file), *args],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=self.env,
            cwd=tmp, start_new_session=True,
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for raw in iter(self.proc.stdout.readline, b""):
            self.line_times.append(time.monotonic())
            self.lines.append(raw.decode(errors="replace").rstrip())

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def wait_for(self, text: str, timeout: float = 20.0) -> str:
        """Block until a line containing ``text`` was printed; returns that line."""
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            for line in list(self.lines):
                if text in line:
                    return line
            if self.proc.poll() is not None and not self._reader.is_alive():
                break
            time.sleep(0.02)
        raise AssertionError(f"no line with {text!r} within {timeout} s; output:\n{self.output}")

    def wait_ready(self, timeout: float = 60.0) -> None:
        """Until the launcher says every node is ready (a deadline against hangs: with the cores
        oversubscribed a graph of scipy/mujoco nodes has taken over 20 s to import)."""
        self.wait_for("nodes ready in", timeout)

    def cli(self, *args: str, timeout: float = 90.0) -> subprocess.CompletedProcess:
        """Run another `mocapgraph` command against this graph (the time-out is a deadline against
        hangs: a heavily loaded machine takes seconds to start an interpreter)."""
        return subprocess.run([sys.executable, "-m", "mocapgraph", *args], env=self.env, capture_output=True,
                              text=True, timeout=timeout)

    def stop(self, timeout: float = 10.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        self._reader.join(timeout=2)
        return self.proc.returncode


def _graph_launcher(folder: Path):
    """(start, started): a factory of LaunchedGraphs run in ``folder`` and the list it fills."""
    started: list[LaunchedGraph] = []

    def start(graph: str | Path, *args: str) -> LaunchedGraph:
        if isinstance(graph, str) and "\n" in graph:
            path = folder / f"graph_{len(started)}.yaml"
            path.write_text(graph)
            graph = path
        g = LaunchedGraph(Path(graph).resolve(), list(args), folder)
        started.append(g)
        return g

    return start, started


@pytest.fixture
def launch_graph(tmp_path: Path):
    """Factory: ``launch_graph(path_or_yaml_text, "arg:=value", ...)`` -> LaunchedGraph (stopped at teardown)."""
    start, started = _graph_launcher(tmp_path)
    yield start
    for g in started:
        g.stop()


@pytest.fixture(scope="module")
def launch_module_graph(tmp_path_factory):
    """Like ``launch_graph``, for a graph shared by the tests of one module (stopped after the last):
    each launch costs seconds of interpreter start-up, so tests that only read from the same graph
    share one."""
    start, started = _graph_launcher(tmp_path_factory.mktemp("graph"))
    yield start
    for g in started:
        g.stop()


class _SharedBrowser:
    """One headless Chromium for consecutive modules that use it (the viewer folder's modules run
    one after another): launching Playwright and Chromium again for each costs about a second.
    Playwright's sync API allows one session a process and runs an event loop on the main thread
    while it lives, so it must end before a test of another module that does not use it (which may
    call ``asyncio.run``): `pytest_runtest_setup` ends it there, and at the end of the session."""

    def __init__(self) -> None:
        self.playwright = None
        self.browser = None
        self.module = None     # the last module that asked for it

    def get(self, module):
        if self.browser is None:
            from browser_support import CHROMIUM, CHROMIUM_ARGS
            from playwright.sync_api import sync_playwright
            self.playwright = sync_playwright().start()
            self.browser = self.playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        self.module = module
        return self.browser

    def end_unless(self, module) -> None:
        """End it before a test of another module that does not use it."""
        if self.browser is not None and module is not self.module:
            self.close()

    def close(self) -> None:
        if self.browser is not None:
            try:
                self.browser.close()
            finally:
                self.playwright.stop()
                self.browser = self.playwright = self.module = None


_BROWSER = _SharedBrowser()


@pytest.fixture(scope="module")
def browser(request):
    """Headless Debian Chromium driven by Playwright, shared by consecutive modules that use it (see
    _SharedBrowser; each test's pages are its own: ``new_page`` opens a fresh context); skipped when
    either is missing."""
    from browser_support import CHROMIUM
    pytest.importorskip("playwright.sync_api", reason="playwright (Python) is not installed")
    if not Path(CHROMIUM).exists():
        pytest.skip(f"chromium is not installed at {CHROMIUM} (apt-get install chromium)")
    yield _BROWSER.get(request.module)


def pytest_runtest_setup(item: pytest.Item) -> None:
    if "browser" not in getattr(item, "fixturenames", ()):
        _BROWSER.end_unless(getattr(item, "module", None))


def pytest_sessionfinish(session: pytest.Session) -> None:
    _BROWSER.close()


# The fast subset (``pytest -m "not slow"``, a few minutes) leaves out what starts processes or a
# browser, or is judged on time: a test asking for one of these fixtures or marked ``timing`` is
# slow by itself; modules slow for other reasons (CLIs as processes, compiles) say so with
# ``pytestmark = pytest.mark.slow``. The full suite (CI) runs everything.
SLOW_FIXTURES = frozenset({"launch_graph", "launch_module_graph", "run_node", "run_module_node", "browser", "open_page",
                           "two_namespaces"})


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("timing") or SLOW_FIXTURES.intersection(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)

