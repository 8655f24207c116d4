"""ROS 2 ``cmd_vel`` into the base's commands, for the bridge (:mod:`omnican.ros2.bridge`).

Each publisher (by its DDS GUID) is a source of commands of the base's own
(:meth:`~omnican.chassis.Chassis.command_source`): one drives at a time, among them and
Foxglove's clients when ``--foxglove-control`` is on; another is ignored, and told so in
the log, until the first has sent nothing for the command timeout. Of what arrived
since the last poll only the newest sample of each publisher is read, the driver's
first, and at most :data:`MAX_PARSED_PER_POLL` of them; the others are dropped unparsed.
A publisher of another type on the cmd_vel topic (DDS does not connect it) is named in
the log once, from DDS discovery.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from omnican.core.kinematics import Twist
from omnican.errors import DriveError
from omnican.errors import quote as _quote
from omnican.log_throttle import Throttle
from omnican.ros2.settings import Ros2Settings
from omnican.ros2.transport import TopicQos, Transport, ros_type_name

if TYPE_CHECKING:
    from omnican.chassis import Chassis
    from omnican.chassis.arbiter import CommandSource

logger = logging.getLogger(__name__)

#: cmd_vel's reader keeps the newest this many samples between polls: enough that the
#: driving publisher's samples survive beside another's flood of 10 kHz (at 100 polls a
#: second about 100 samples arrive per poll), few enough that taking them is cheap.
CMD_VEL_DEPTH = 256
#: A Twist is 52 bytes on the wire, a TwistStamped 76 plus its frame id: a larger sample
#: is refused before it is parsed.
MAX_CMD_BYTES = 1024
#: Quoted values and texts from clients are cut to this many characters in the log.
QUOTE_CHARS = 60
#: At most this many samples are parsed a poll: the driver's, and while no one drives,
#: those of a few others that may take control (so many writers cost no more than few).
MAX_PARSED_PER_POLL = 4
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
        # publication handle -> its source of commands
        self._writers: dict[int, CommandSource] = {}
        self._told_types: set[str] = set()
        self._throttle = Throttle(logger)
        self.driver: str | None = None  # the source that drove last
        self.received = 0  # samples taken from DDS
        self.parsed = 0  # the newest of a publisher's samples, parsed
        self.rejected = 0  # unreadable, not finite, or refused by the base
        self.refused = 0  # ignored: another source held control
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
        sources = {writer: self._source(writer) for writer in newest}
        holder = next(iter(sources.values())).holder() if sources else None
        parsed = 0
        # The driver's sample first; another's only while no one drives (then it is
        # parsed to see whether it may take control), a few a poll at most.
        for writer in sorted(newest, key=lambda w: sources[w].name != holder):
            source = sources[writer]
            other = source.may_act()
            if other is not None:
                self._refuse(source, other)
            elif parsed < MAX_PARSED_PER_POLL:
                parsed += 1
                self._on_cmd_vel(source, newest[writer])

    def flush(self) -> None:
        """Log what the throttle held back."""
        self._throttle.flush()

    def _source(self, writer: int) -> CommandSource:
        source = self._writers.get(writer)
        if source is None:
            guid = self.transport.writer_guid(self.topic, writer)
            source = self.base.command_source(f"{CMD_VEL_SOURCE} publisher "
                                              f"{guid or hex(writer)}")
            if len(self._writers) > 1000:  # writers come and go; do not grow for ever
                self._writers.clear()
            self._writers[writer] = source
        return source

    def _on_cmd_vel(self, source: CommandSource, data: bytes) -> None:
        self.parsed += 1
        if len(data) > MAX_CMD_BYTES:
            self._reject(source, f"a {len(data)}-byte sample, not read (more than the "
                         f"{MAX_CMD_BYTES} bytes a {self._type_name()} may have here)")
            return
        try:
            msg = self.cmd_type.deserialize(data)
        except Exception as exc:  # whatever a broken sample raises
            self._reject(source, f"cannot be read as a {self._type_name()}: {quote(str(exc))}")
            return
        twist = msg.twist if self.settings.cmd_vel_stamped else msg
        t = twist_from_msg((twist.linear.x, twist.linear.y, twist.linear.z),
                           (twist.angular.x, twist.angular.y, twist.angular.z))
        if not t.is_finite():
            self._reject(source, f"not finite: vx={quote(t.vx)} vy={quote(t.vy)} "
                         f"wz={quote(t.wz)}")
            return
        try:
            holder = source.send(t)
        except ValueError as exc:
            self._reject(source, quote(str(exc), 200))
            return
        except DriveError:
            return  # closing
        if holder is not None:  # someone else drives (another publisher, a Foxglove client)
            self._refuse(source, holder)
            return
        if self.driver != source.name:
            self.driver = source.name
            logger.info("%s drives the base", source.name)

    def _refuse(self, source: CommandSource, holder: str) -> None:
        self.refused += 1
        self._throttle.warning(("refused", source.name), "cmd_vel from %s ignored: %s is "
                               "driving the base (one publisher at a time; it drives once "
                               "%s has sent nothing for %g s)", source.name, holder, holder,
                               source.timeout_s)

    def _reject(self, source: CommandSource, why: str) -> None:
        self.rejected += 1
        self._throttle.warning(("rejected", source.name), "cmd_vel from %s ignored: %s",
                               source.name, why)

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
