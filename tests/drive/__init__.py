"""Tests of :mod:`omnican.drive`."""
