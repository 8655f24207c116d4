"""Tests of :mod:`omnican.gamepad`."""
