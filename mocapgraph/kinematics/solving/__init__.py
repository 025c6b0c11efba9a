"""Frame solving: joint positions from labelled markers and a calibrated ActorModel, per frame or batched.

`solver` (the FrameSolver, Kiip 3.4), `rigid` (weighted Kabsch fits of marker clusters),
`global_fit` / `global_track` (all limbs of a frame together under the joint constraints),
`regression` (Plug-in Gait joint centres), `filters` (gap filling, smoothing); each
`*_kernels.py` is the compiled one-frame twin of the numpy code beside it.
"""
