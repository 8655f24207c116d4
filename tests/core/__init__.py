"""Tests of :mod:`omnican.core`."""
