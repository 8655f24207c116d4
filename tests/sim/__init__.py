"""Tests of :mod:`omnican.sim`."""
