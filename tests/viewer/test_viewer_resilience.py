"""What a browser does to the viewer: reload, two tabs, a tab in the background, the graph restarting."""
from __future__ import annotations


from viewer_support import TESTING, free_port, viewer_stats, viewer_url, wait_until

LIVE = "s.connected && s.markersDrawn > 0 && s.jointsDrawn === 16"


def _graph(port: int) -> str:
    return f"""
nodes:
  - name: alice
    type: {TESTING}:StagePerformer
    params: {{actor: alice, rate_hz: 120.0, publish: [markers, actor]}}
  - name: viz
    type: visualizer
    params: {{port: {port}}}
"""


def _client(url: str, cid: int) -> dict:
    return next(c for c in viewer_stats(url)["clients"] if c["id"] == cid)


def test_reload_two_tabs_background_and_restart(launch_graph, open_page):
    port = free_port()
    g = launch_graph(_graph(port))
    g.wait_ready()
    url = viewer_url(g)
    a = open_page(url)
    a.wait(LIVE, timeout=15)

    # Reload: a new connection replaces the old one.
    a.page.reload()
    a.wait(LIVE)
    wait_until(lambda: len(viewer_stats(url)["clients"]) == 1, what="the old tab's connection to close")

    # Two tabs at once, both live.
    b = open_page(url)
    b.wait(LIVE)
    assert len(viewer_stats(url)["clients"]) == 2
    ca, cb = a.wait("s.client"), b.wait("s.client")
    assert ca != cb

    # A tab in the background runs no animation frames, so it acknowledges nothing. Headless Chromium
    # never hides a page (freezing or minimising leave requestAnimationFrame running), so the test
    # stops the tab's scripts in the debugger instead: it then holds at most its window of bundles,
    # the other tab goes on at full pace, and it resumes without reconnecting.
    cdp = a.page.context.new_cdp_session(a.page)
    cdp.send("Debugger.enable")
    cdp.send("Debugger.pause")
    # Until the live tab has had 40 more bundles (an event, however slow a busy machine makes it),
    # the paused one gets at most its window of 2 (one may have been in flight at the pause).
    sa0, sb0 = _client(url, ca)["bundles"], _client(url, cb)["bundles"]
    wait_until(lambda: _client(url, cb)["bundles"] > sb0 + 40, timeout=30, what="the live tab to go on")
    sa1 = _client(url, ca)["bundles"]
    assert sa1 - sa0 <= 2 and sa1 - _client(url, ca)["acks"] <= 2
    cdp.send("Debugger.resume")
    cdp.send("Debugger.disable")
    frames = a.stats()["framesDrawn"]
    a.wait(f"s.framesDrawn > {frames} + 10")
    wait_until(lambda: _client(url, ca)["bundles"] > sa1 + 10, what="the resumed tab to get bundles again")
    assert a.stats()["connects"] == 1

    # The graph restarts under both tabs: they notice, and reconnect by themselves.
    g.stop()
    a.wait("!s.connected")
    b.wait("!s.connected")
    g2 = launch_graph(_graph(port))
    g2.wait_ready()
    assert viewer_url(g2) == url  # the token is kept per user and port, so open tabs get back in
    for tab in (a, b):
        tab.wait(f"s.connects === 2 && {LIVE}", timeout=20)
    assert len(viewer_stats(url)["clients"]) == 2
    assert a.errors() == [] and b.errors() == []
    assert a.stats()["errors"] == [] and b.stats()["errors"] == []
