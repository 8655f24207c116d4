"""Offline and bus analysis: calibration, traffic and bus load, scan."""
