"""The web viewer behind the `visualizer` node: wire format, server and the page's assets.

The page (index.html, viewer.css, js/*.js) is package data served by `server.ViewerServer`;
nothing is fetched from the internet. The small real nodes that feed it in tests, the
benchmark and example graphs live in :mod:`mocapgraph.testing.viewer_nodes`.
"""
from pathlib import Path

ASSET_DIR = Path(__file__).resolve().parent
