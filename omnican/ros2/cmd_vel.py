"""ROS 2 ``cmd_vel`` into the base's commands, for the bridge (:mod:`omnican.ros2.bridge`).

Each publisher (by its DDS GUID) is a source of commands of the base's own
(:meth:`~omnican.chassis.Chassis.command_source`): one drives at a time, among them and
Foxglove's clients when ``--foxglove-control`` is on; another is ignored, and told so in
the log, until the first has sent nothing for the command timeout. Of what arrived
since the last poll only the newest sample of each publisher is read, the driver's
first, and at most :data:`MAX_PARSED_PER_POLL` of them; the others are dropped unparsed
(:mod:`omnican.command.intake`, which the Zenoh front end shares).
A publisher of another type on the cmd_vel topic (DDS does not connect it) is named in
the log once, from DDS discovery.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from omnican.command.intake import MAX_CMD_BYTES, MAX_PARSED_PER_POLL, QUOTE_CHARS, CmdVelIntake
from omnican.core.kinematics import Twist
from omnican.errors import quote as _quote
from omnican.ros2.settings import Ros2Settings
from omnican.ros2.transport import TopicQos, Transport, ros_type_name

if TYPE_CHECKING:
    from omnican.chassis import Chassis
    from omnican.chassis.arbiter import CommandSource

__all__ = ["CMD_VEL_DEPTH", "MAX_CMD_BYTES", "MAX_PARSED_PER_POLL", "QUOTE_CHARS", "CmdVel",
           "quote", "twist_from_msg"]

logger = logging.getLogger(__name__)

#: cmd_vel's reader keeps the newest this many samples between polls: enough that the
#: driving publisher's samples survive beside another's flood of 10 kHz (at 100 polls a
#: second about 100 samples arrive per poll), few enough that taking them is cheap.
CMD_VEL_DEPTH = 256
#: At most this many writers of a wrong type are named (a hostile peer may make many).
MAX_NAMED_WRITERS = 100
CMD_VEL_SOURCE = "ROS 2 cmd_vel"  # what the other sources of commands are told


def quote(value: object, limit: int = QUOTE_CHARS) -> str:
    """``repr(value)`` cut to ``limit`` characters (:func:`omnican.errors.quote`)."""
    return _quote(value, limit)


def twist_from_msg(linear: Sequence[float], angular: Sequence[float]) -> Twist:
    """The planar part of a geometry_msgs/Twist (x, y linear; z angular)."""
    return Twist(float(linear[0]), float(linear[1]), float(angular[2]))


class CmdVel:
    """The cmd_vel reader of a bridge and what it did (see the module docstring). Its
    owner calls :meth:`take` from one thread at a time."""

    def __init__(self, base: Chassis, settings: Ros2Settings, transport: Transport) -> None:
        from omnican.ros2 import msgs

        self.base = base
        self.settings = settings
        self.transport = transport
        self.cmd_type: type[Any] = msgs.TwistStamped if settings.cmd_vel_stamped else msgs.Twist
        self.topic = settings.topic("cmd_vel")
        self._take = transport.reader(self.topic, self.cmd_type, TopicQos(depth=CMD_VEL_DEPTH))
        # publication handle -> its source of commands, and its GUID
        self._writers: dict[int, CommandSource] = {}
        self._guids: dict[int, str] = {}
        self._told_types: set[str] = set()
        #: what became of the samples (parsed, rejected, refused, the driver)
        self.intake = CmdVelIntake(logger, self._type_name(), self._read)
        self.received = 0  # samples taken from DDS
        self.wrong_types: dict[str, str] = {}  # cmd_vel writers of another type: guid -> type

    def take(self, check_publications: bool = False) -> None:
        """Take what arrived and act on it: the newest sample of each publisher, the others
        dropped unparsed; with ``check_publications``, name new writers of another type."""
        if check_publications:
            self._check_publications()
        received = self._take()
        self.received += len(received)
        newest: dict[int, bytes] = {}
        for r in received:  # oldest first: the last of each writer stays
            newest.pop(r.writer, None)
            newest[r.writer] = r.data
        self.intake.take({self._source(writer): data for writer, data in newest.items()})

    def flush(self) -> None:
        """Log what the throttle held back."""
        self.intake.flush()

    @property
    def driver(self) -> str | None:
        """The source that drove last."""
        return self.intake.driver

    @property
    def parsed(self) -> int:
        return self.intake.parsed

    @property
    def rejected(self) -> int:
        return self.intake.rejected

    @property
    def refused(self) -> int:
        return self.intake.refused

    def _source(self, writer: int) -> CommandSource:
        source = self._writers.get(writer)
        if source is None:
            guid = self.transport.writer_guid(self.topic, writer)
            source = self.base.command_source(f"{CMD_VEL_SOURCE} publisher "
                                              f"{guid or hex(writer)}")
            if len(self._writers) > 1000:  # writers come and go; do not grow for ever
                self._writers.clear()
                self._guids.clear()
            self._writers[writer] = source
            self._guids[writer] = guid
        return source

    def of_participant(self, guid: str) -> CommandSource | None:
        """The cmd_vel source of the DDS participant (a ROS 2 process: its writers' GUIDs
        share their first 12 bytes) that has the writer ``guid`` (hex), the one that
        drives if it has several; None if none of its writers has sent."""
        if len(guid) != 32:
            return None
        mine = [self._writers[w] for w, g in self._guids.items() if g[:24] == guid[:24]]
        if not mine:
            return None
        driver = mine[0].holder()
        return next((s for s in mine if s.name == driver), mine[-1])

    def _read(self, data: bytes) -> Twist:
        msg = self.cmd_type.deserialize(data)
        twist = msg.twist if self.settings.cmd_vel_stamped else msg
        return twist_from_msg((twist.linear.x, twist.linear.y, twist.linear.z),
                              (twist.angular.x, twist.angular.y, twist.angular.z))

    def _type_name(self) -> str:
        return ros_type_name(self.cmd_type.__idl_typename__)

    def _check_publications(self) -> None:
        """Name once each cmd_vel writer of another type: DDS does not connect it, so
        nothing of it arrives, and without this nothing would say why the base stands."""
        ours = self._type_name()
        for pub in self.transport.publications():
            if pub.topic != self.topic or pub.type_name == ours:
                continue
            if pub.guid in self._told_types or len(self._told_types) >= MAX_NAMED_WRITERS:
                continue
            self._told_types.add(pub.guid)
            self.wrong_types[pub.guid] = pub.type_name
            if pub.type_name.endswith("/TwistStamped"):
                hint = "start with --cmd-vel-stamped (or [ros2] cmd_vel_stamped = true)"
            elif pub.type_name.endswith("/Twist"):
                hint = "start without --cmd-vel-stamped ([ros2] cmd_vel_stamped = false)"
            else:
                hint = ("it takes geometry_msgs/msg/Twist, or TwistStamped with "
                        "--cmd-vel-stamped")
            logger.warning("%s: publisher %s sends %s but this node reads %s: its commands "
                           "are not received; %s", self.topic, pub.guid,
                           quote(pub.type_name), ours, hint)
