"""Pure math on arrays: rigid fits, label placement, layouts, calibration, the frame solver, the synthetic actor.

Units: metres, seconds, radians; world frame Z up, X forward; missing = NaN. Nothing here
imports the bus or the messages codec (only the quality codes of :mod:`mocapgraph.messages.quality`).
"""
