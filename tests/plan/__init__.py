"""Tests of :mod:`omnican.plan`."""
