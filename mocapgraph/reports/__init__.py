"""Figures and pages for people: calibration reports (matplotlib)."""
