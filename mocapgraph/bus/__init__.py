"""Publish/subscribe over ZeroMQ and the node runtime (event loop, timers, params, stats)."""
from .node import Node, NodeConfigError, Timer
from .ports import Input, Interface, Output, Param, ParamError
from .protocol import Wiring

__all__ = ["Node", "NodeConfigError", "Timer", "Wiring", "Input", "Interface", "Output", "Param", "ParamError"]
