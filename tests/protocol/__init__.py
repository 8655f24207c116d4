"""Tests of :mod:`omnican.protocol`."""
