"""Conversions between the math's types (kinematics/) and messages (messages/)."""
