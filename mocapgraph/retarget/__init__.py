"""Retargeting: a performer's motion onto a character, as pure math on arrays (no bus).

Bottom up: `character` (the target skeleton), `joint_roles` and `mapping` (which source joint drives
which character joint, Claro's Eq 4.1), `source` (the source skeleton, rotations from points),
`bone_follow` and `foot_planting` (quality and contact), `kernels` and `source_kernels` (the compiled
one-frame arithmetic), `live` (the one-frame path), `retargeter` (the batched reference and the
entry points the node and the CLI call), `warmup` (compiles every kernel once).

Units: metres, seconds, radians; world frame Z up; quaternions (w, x, y, z); missing = NaN.
"""
