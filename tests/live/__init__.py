"""Tests of :mod:`omnican.live`."""
