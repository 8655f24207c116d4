"""Exceptions raised by omnican.

Every error a user can cause (bad config, bad EDS, bad command) is a subclass of
:class:`ConfigError` or :class:`ValueError` with a message that names the problem,
so the CLI can print it as one line.
"""

from __future__ import annotations


class OmnicanError(Exception):
    """Base class of omnican's run-time errors."""


class ConfigError(OmnicanError, ValueError):
    """A configuration, geometry or EDS problem; the message names the key and the problem."""


class DriveError(OmnicanError):
    """A drive did not do what it was asked (SDO abort, timeout, refused transition, fault)."""


class BusError(OmnicanError):
    """The CAN bus could not be opened or went down."""
