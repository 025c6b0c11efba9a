"""The synthetic actor: labelled marker trajectories of a scripted human, with their exact ground truth.

`body` (segments, joint centres, degrees of freedom), `motion` (the script: joint angles as
functions of time), `actor` (markers on the moving body, with dropouts, shadows and swaps) and
`truth` (the skeleton model a perfect calibration would give).
"""
