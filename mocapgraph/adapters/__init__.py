"""Conversions between the math's types (kinematics/) and messages (messages/); no bus, no math.

``model_messages`` (ActorModel <-> SkeletonModel, poses, quality report), ``model_store`` (a
node's model saved and as a message), ``layout_binding`` (a marker stream bound to a layout),
``calibration_report`` (what the calibration node reports).
"""
