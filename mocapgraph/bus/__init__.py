"""Publish/subscribe over ZeroMQ and the node runtime (event loop, timers, params, stats).

Also what the launcher, the nodes and the tools share below them: the graph's `manifest` (built and
served by the launcher, fetched by `topic echo`, `bag record` and friends) and the per-user run
directory (`user_dir`) that holds its socket and the viewer's tokens.
"""
from .node import Node, NodeConfigError, Timer
from .ports import Input, Interface, Output, Param, ParamError
from .protocol import Wiring

__all__ = ["Node", "NodeConfigError", "Timer", "Wiring", "Input", "Interface", "Output", "Param", "ParamError"]
