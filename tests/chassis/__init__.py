"""Tests of :mod:`omnican.chassis`."""
