"""The gamepad front end: a Linux evdev gamepad driving the teleop command model."""

from omnican.gamepad.device import Gamepad

__all__ = ["Gamepad"]
