"""Recordings: python-can log formats, MCAP, replay."""
