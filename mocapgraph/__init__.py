"""mocapgraph: motion capture as a graph of processes on a ZeroMQ bus (the package root; see README.md).

Layers, bottom up: ``messages``, ``formats`` and ``kinematics`` (math on arrays, no bus), then
``bus`` (the node runtime), ``adapters`` (kinematics <-> messages), ``bag``, ``viewer``, ``nodes``
(one module per node type), ``launch`` (graphs and supervision) and ``cli`` (the command).
"""
