"""Tests of :mod:`omnican.analysis`."""
