"""The page names a node whose diagnostics stopped for 3 s (SIGSTOP) as stalled, through a reconnect, and clears it."""
from __future__ import annotations

import os
import signal

from graph_helpers import node_pids
from viewer_support import free_port, viewer_url


def test_the_page_lists_a_stopped_node_as_stalled(launch_graph, open_page) -> None:
    port = free_port()
    g = launch_graph(f"""
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: 60.0}}
  - name: viz
    type: visualizer
    params: {{port: {port}}}
""")
    g.wait_ready()
    page = open_page(viewer_url(g))
    page.wait("s.connected && s.framesDrawn > 3 && Array.isArray(s.stalled)", timeout=20)
    # the page can only miss a node it has heard from: wait for pattern's first diagnostics (1 Hz),
    # else a quick machine stops it before it ever reported
    page.wait('window.mocapgraphViewer.store.ofType("Diagnostics").some((d) => (d.fields.node || d.sender) === "pattern")',
              timeout=10)
    assert page.stats()["stalled"] == []
    pid = node_pids(g)["pattern"]
    os.kill(pid, signal.SIGSTOP)
    try:
        page.wait('s.stalled.includes("pattern")', timeout=10)
        assert "viz" not in page.stats()["stalled"]
        assert "pattern" in page.page.locator("#stalled-nodes").inner_text()
        # the link drops and comes back: the server sends every stream's newest message again,
        # the stopped node's last diagnostics among them; that is no sign of life
        connects = page.stats()["connects"]
        page.page.evaluate("() => window.mocapgraphViewer.link.ws.close()")
        page.wait(f"s.connected && s.connects > {connects} && s.bundles > 0", timeout=10)
        page.wait("s.framesDrawn > 0", timeout=5)
        page.page.wait_for_timeout(600)   # a few panel refreshes (4 a second) after the resend
        assert "pattern" in page.stats()["stalled"], page.stats()["stalled"]
    finally:
        os.kill(pid, signal.SIGCONT)
    page.wait("s.stalled.length === 0", timeout=10)
    assert page.errors() == []
