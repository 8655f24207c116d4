"""cmd_vel from a network into the base, as the ROS 2 and Zenoh front ends take it alike.

A front end reads what arrived since its last poll and hands :meth:`CmdVelIntake.take`
the newest sample of each publisher, each publisher a command source of the base's own
(:meth:`~omnican.chassis.Chassis.command_source`). The driver's sample goes first;
another's is parsed only while no one drives (to see whether it may take control), at
most :data:`MAX_PARSED_PER_POLL` a poll, so many writers cost no more than few. A sample
that cannot be a command (over :data:`MAX_CMD_BYTES`, unreadable, not finite, beyond
any base) is refused with a log line per publisher every few seconds at most, and moves
nothing; one from a publisher that another source keeps from driving is ignored and
said so. How a sample is read (DDS's types, or CDR from Zenoh) is the front end's.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

from omnican.chassis.actions import Action
from omnican.core.kinematics import Twist
from omnican.errors import DriveError, quote
from omnican.log_throttle import Throttle

if TYPE_CHECKING:
    from omnican.chassis.arbiter import CommandSource

#: A Twist is 52 bytes on the wire, a TwistStamped 76 plus its frame id: a larger sample
#: is refused before it is parsed.
MAX_CMD_BYTES = 1024
#: Quoted values and texts from clients are cut to this many characters in the log.
QUOTE_CHARS = 60
#: At most this many samples are parsed a poll: the driver's, and while no one drives,
#: those of a few others that may take control.
MAX_PARSED_PER_POLL = 4


class CmdVelIntake:
    """What one front end did with cmd_vel (see the module docstring): ``read`` turns a
    sample's bytes into a :class:`Twist` (raising whatever a broken sample raises),
    ``type_name`` names what a sample should be in the log. Its owner calls :meth:`take`
    from one thread at a time."""

    def __init__(self, log: logging.Logger, type_name: str,
                 read: Callable[[bytes], Twist]) -> None:
        self.type_name = type_name
        self._read = read
        self._throttle = Throttle(log)
        self._log = log
        self.driver: str | None = None  # the source that drove last
        self.parsed = 0  # the newest of a publisher's samples, parsed
        self.rejected = 0  # unreadable, not finite, or refused by the base
        self.refused = 0  # ignored: another source held control

    def take(self, newest: Mapping[CommandSource, bytes]) -> None:
        """Act on the newest sample of each publisher (in the order they arrived)."""
        holder = next(iter(newest)).holder() if newest else None
        parsed = 0
        for source in sorted(newest, key=lambda s: s.name != holder):
            asked = source.may(Action.DRIVE)  # the base says; a refused one is not parsed
            if asked.refused_by is not None:
                self.refuse(source, asked.refused_by)
            elif parsed < MAX_PARSED_PER_POLL:
                parsed += 1
                self._on_sample(source, newest[source])

    def _on_sample(self, source: CommandSource, data: bytes) -> None:
        self.parsed += 1
        if len(data) > MAX_CMD_BYTES:
            self.reject(source, f"a {len(data)}-byte sample, not read (more than the "
                        f"{MAX_CMD_BYTES} bytes a {self.type_name} may have here)")
            return
        try:
            t = self._read(data)
        except Exception as exc:  # whatever a broken sample raises
            self.reject(source, f"cannot be read as a {self.type_name}: "
                        f"{quote(str(exc), QUOTE_CHARS)}")
            return
        if not t.is_finite():
            self.reject(source, f"not finite: vx={quote(t.vx, QUOTE_CHARS)} "
                        f"vy={quote(t.vy, QUOTE_CHARS)} wz={quote(t.wz, QUOTE_CHARS)}")
            return
        try:
            sent = source.drive(t)
        except ValueError as exc:
            self.reject(source, quote(str(exc), 200))
            return
        except DriveError:
            return  # closing
        if sent.refused_by is not None:  # someone else drives (a publisher, a Foxglove client)
            self.refuse(source, sent.refused_by)
            return
        if self.driver != source.name:
            self.driver = source.name
            self._log.info("%s drives the base", source.name)

    def refuse(self, source: CommandSource, holder: str) -> None:
        """``source``'s command ignored: ``holder`` drives."""
        self.refused += 1
        self._throttle.warning(("refused", source.name), "cmd_vel from %s ignored: %s is "
                               "driving the base (one publisher at a time; it drives once "
                               "%s has sent nothing for %g s)", source.name, holder, holder,
                               source.timeout_s)

    def reject(self, source: CommandSource, why: str) -> None:
        """``source``'s sample refused: ``why``."""
        self.rejected += 1
        self._throttle.warning(("rejected", source.name), "cmd_vel from %s ignored: %s",
                               source.name, why)

    def flush(self) -> None:
        """Log what the throttle held back."""
        self._throttle.flush()
