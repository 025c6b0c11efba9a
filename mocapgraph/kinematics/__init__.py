"""Pure math on arrays: the actor's description (layouts, skeleton, labels, model) and its domains below.

Sub-parts, bottom up: `solving` (rigid fits, the frame solver, the global fit), `calibration`
(base pose and gym to an ActorModel), `synthetic` (the scripted actor with exact ground truth).
The files beside this one describe the actor that every domain shares: `layout` (the marker
layout files), `skeleton`, `labels`, `model` (the calibrated ActorModel) and `subject`.

Units: metres, seconds, radians; world frame Z up, X forward; missing = NaN. Nothing here
imports the bus or the messages codec (only the quality codes of :mod:`mocapgraph.messages.quality`).
"""
