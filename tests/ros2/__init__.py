"""Tests of :mod:`omnican.ros2`."""
