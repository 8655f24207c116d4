"""Tests of :mod:`omnican.telemetry`."""
