"""Tests of :mod:`omnican.config`."""
