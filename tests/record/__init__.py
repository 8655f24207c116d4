"""Tests of :mod:`omnican.record`."""
