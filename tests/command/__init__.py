"""Tests of :mod:`omnican.command`."""
