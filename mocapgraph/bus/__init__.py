"""Publish/subscribe over ZeroMQ and the node runtime (event loop, timers, params, stats)."""
from .node import Node, NodeConfigError, Wiring
from .ports import Input, Interface, Output, Param, ParamError

__all__ = ["Node", "NodeConfigError", "Wiring", "Input", "Interface", "Output", "Param", "ParamError"]
