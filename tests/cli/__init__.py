"""Tests of :mod:`omnican.cli`."""
