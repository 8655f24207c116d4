"""What a front end may do to a base, and who may do each: the one table (:data:`RULES`).

A front end (the terminal's keys, a gamepad, a ROS 2 or Zenoh client, a Foxglove client)
acts on the base only through the handle it got from it
(:class:`~omnican.chassis.arbiter.CommandSource`), and the base's arbiter answers each
action from this table, at the moment it is asked, by who then drives (holds control):

- **anyone** may stop the base (:attr:`Action.STOP`, :attr:`Action.HALT`), whoever drives:
  a stop is not a command. A stop by another source also takes control from the one
  driving, which is refused until it has let go (sent nothing for the command timeout);
- **the driver, or anyone while no one drives** may do the rest: drive (the first to
  send then drives), recover, reset the odometry, change a limit, use the simulator's
  console.

Each action's :class:`Outcome` says what became of it: done, refused (by whom: who
drives), or failed (what the base said). A front end says it in its own words; it decides
nothing.

Pure: no I/O, no threads.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType


class Action(enum.Enum):
    """An operator's action on a base, named as the docs' table names it."""

    DRIVE = "drive"  # send a velocity (CommandSource.drive)
    STOP = "stop"  # a controlled stop; the next command moves again
    HALT = "halt"  # a stop held until a recover (Zenoh's ~/stop, the fleet stop)
    RECOVER = "recover"
    RESET_POSE = "reset the odometry"
    SET_LIMITS = "change a limit"
    SIM_CONSOLE = "use the simulator's console"

    @property
    def stops(self) -> bool:
        """A stop: it takes control from whoever drove (until that source lets go)."""
        return self in (Action.STOP, Action.HALT)


class Rule(enum.Enum):
    """Who may take an action, by who drives the base when it is asked."""

    ANYONE = "anyone"
    DRIVER_OR_NOBODY = "the driver, or anyone while no one drives"


#: Who may take each action: the one table (the docs' "Who may act" table is this one).
RULES: Mapping[Action, Rule] = MappingProxyType({
    Action.DRIVE: Rule.DRIVER_OR_NOBODY,
    Action.STOP: Rule.ANYONE,
    Action.HALT: Rule.ANYONE,
    Action.RECOVER: Rule.DRIVER_OR_NOBODY,
    Action.RESET_POSE: Rule.DRIVER_OR_NOBODY,
    Action.SET_LIMITS: Rule.DRIVER_OR_NOBODY,
    Action.SIM_CONSOLE: Rule.DRIVER_OR_NOBODY,
})


def refuser(action: Action, source: str, driver: str | None) -> str | None:
    """Who keeps ``source`` from taking ``action`` while ``driver`` drives (None: no one
    does), by :data:`RULES`."""
    rule = RULES[action]
    if rule is Rule.ANYONE or driver is None or driver == source:
        return None
    return driver


@dataclass(frozen=True)
class Outcome:
    """What became of ``source``'s ``action`` (or, from
    :meth:`~omnican.chassis.arbiter.CommandSource.may`, what would): done when
    :attr:`ok`; else refused by :attr:`refused_by` (the source that drives) or
    :attr:`failed` (the base's own refusal or failure, in its words: a fault it cannot
    reset, a pose beyond sense, a limit above the config's)."""

    action: Action
    source: str
    refused_by: str | None = None
    failed: str | None = None
    #: a stop from another than the driver: the source it took control from
    took_from: str | None = None

    @property
    def ok(self) -> bool:
        return self.refused_by is None and self.failed is None

    @property
    def rule(self) -> Rule:
        return RULES[self.action]

    @property
    def why(self) -> str:
        """One line: why it was refused or failed ("" when done)."""
        if self.refused_by is not None:
            return (f"{self.refused_by} is driving; only it may {self.action.value} now "
                    "(anyone may stop)")
        return self.failed or ""
