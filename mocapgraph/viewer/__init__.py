"""The web viewer behind the `visualizer` node: wire format, server and the page's assets.

The page (index.html, viewer.css, js/*.js) is package data served by `server.ViewerServer`;
nothing is fetched from the internet. `testing_nodes` holds small real nodes used by the
viewer's tests, benchmark and example graphs.
"""
from pathlib import Path

ASSET_DIR = Path(__file__).resolve().parent
