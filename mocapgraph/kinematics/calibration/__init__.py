"""Actor calibration: joint centres and bone lengths of a performer from a base pose and a gym capture.

`calibrate` (the batch fit, Kiip 3.3), `capture_steps` (the same steps fed live, one frame at a
time), `centres` (anatomical and regression candidates), `consistency` (clusters file against
file) and `marker_residuals` (how well a calibrated model explains its capture). Built on
`kinematics.solving` (rigid fits, the frame solver) and the actor's description above it.
"""
