"""Driving from Foxglove: what clients of the live view may send the base, when control
is on (``--foxglove-control``).

- **Twists** on the control topic (``/cmd_vel``; Foxglove's Teleop panel), as JSON or CDR,
  ``geometry_msgs/Twist`` or ``TwistStamped``: each goes to :meth:`Chassis.set_twist`,
  so the same limits and watchdog apply as to every other command. One controller at a
  time (the base's :meth:`~omnican.chassis.Chassis.command_source`, each client one
  source; shared with the front end's other sources): the first client that publishes holds
  control until it leaves or sends nothing for ``cmd_timeout_s``; another client's
  commands are ignored and a status message says who is driving. The base stops at once
  when the controlling client leaves. A Twist that cannot be read (NaN, a wrong type)
  moves nothing; from the controller it stops the base.
- **Services** (:mod:`omnican.live.services`): ``/omnican/stop`` (anyone, at any time),
  ``/omnican/recover``, ``/omnican/reset_odometry``, and under simulation
  ``/omnican/sim/console``.
- **Parameters** named as the config's keys (``chassis.max_speed``, ...; the limits of
  :data:`omnican.config.LIVE_LIMITS`), read and set live through
  :meth:`Chassis.set_limits` (the config's checks); a refused value keeps the old one and
  a status message gives the reason. An unlimited speed (inf in the config) reads as the
  top speed the base can reach under its other limits (:func:`omnican.core.limits.top_speeds`:
  the wheel limit's), a number; set back, it is a limit at that speed, which changes
  nothing the base does.

While one client drives, only it may recover, reset odometry, change a parameter or
inject a fault: each client is a command source of the base's, whose answers
(:mod:`omnican.chassis.actions`) this module only words. The SDK calls these methods on
its own threads; none of them blocks the control loop.

Only a client the relay vouched for (:mod:`omnican.live.relay`: its web page allowed, the
token given when one is set) may do any of this; the others, and whoever reaches the SDK's
own port past the relay, may watch and read the parameters, nothing more. Every message is
read with care (:mod:`omnican.live.requests`: measured first, junk refused).
"""

from __future__ import annotations

import logging
import math
import secrets
import threading
from dataclasses import dataclass
from typing import Any

from omnican.chassis.actions import Action
from omnican.chassis.arbiter import CommandSource
from omnican.config import LIVE_LIMITS
from omnican.core.limits import top_speeds
from omnican.errors import quote
from omnican.live.relay import GRANT_CHANNEL_ID, GRANT_PREFIX
from omnican.live.requests import decode_twist, parameter_value
from omnican.live.services import Services
from omnican.live.settings import FoxgloveSettings
from omnican.log_throttle import Throttle

logger = logging.getLogger(__name__)

ENCODINGS = ["json", "cdr"]  # what clients may publish in; Foxglove picks the first
PARAMETERS = tuple(f"chassis.{key}" for key in LIVE_LIMITS)
_STATUS_DRIVER, _STATUS_REFUSED = "omnican.control", "omnican.control.refused"
_GRANTS_PENDING_MAX = 256  # keys given to the relay and not yet used (connections opening)


@dataclass(frozen=True)
class _Channel:
    topic: str
    encoding: str
    schema_name: str


class Control:
    """What Foxglove clients may do to ``base`` (see the module docstring): the SDK
    server's listener and services. ``sim``: a simulated base, for its fault console."""

    def __init__(self, base: Any, settings: FoxgloveSettings, sim: Any = None) -> None:
        self.base = base
        self.settings = settings
        self.sim = sim
        self.services = Services(self)
        self._server: Any = None
        self._status_level: Any = None
        self._lock = threading.Lock()
        self._channels: dict[tuple[int, int], _Channel] = {}
        self._told: set[str] = set()  # refused sources told since control last changed
        self._driver: str | None = None  # who drove last (for the status message)
        self._closed = False
        self._throttle = Throttle(logger)
        self._grants: set[str] = set()  # keys given to the relay, not yet used
        self._drivers: set[int] = set()  # clients the relay vouched for
        self.twists = 0  # commands that reached the base
        self.refused = 0  # commands refused (someone else drives, or unreadable)

    @staticmethod
    def source(client_id: int) -> str:
        return f"Foxglove client {client_id}"

    def commands(self, source: str) -> CommandSource:
        """The base's handle for ``source``: every command and stop goes through it."""
        handle: CommandSource = self.base.command_source(source)
        return handle

    @property
    def closed(self) -> bool:
        """The server is stopping: nothing reaches the base any more."""
        return self._closed

    def driver_stopped(self, driver: str) -> None:
        """Another client's stop took control from ``driver``: it is told why at its next
        command, and no one drives."""
        with self._lock:
            self._told.discard(driver)
            self._driver = None

    @property
    def timeout_s(self) -> float:
        """How long a silent driver keeps control (the base's command timeout)."""
        return self.commands("Foxglove").timeout_s  # the same for every source of a base

    def service_names(self) -> list[str]:
        return self.services.service_names()

    def _services(self, foxglove: Any) -> list[Any]:
        return self.services.build(foxglove)

    # ------------------------------------------------------------ who may drive

    def grant(self) -> str:
        """A one-time key by which the relay vouches for a connection that may drive
        (:func:`omnican.live.relay.grant_frame`)."""
        key = secrets.token_hex(16)
        with self._lock:
            if len(self._grants) >= _GRANTS_PENDING_MAX:
                self._grants.pop()  # a connection that never reached the server
            self._grants.add(key)
        return key

    def may_drive(self, client_id: int) -> bool:
        with self._lock:
            return client_id in self._drivers

    def watcher(self, client_id: int, what: str) -> str | None:
        """None if the client may drive; else the reason it may not do ``what``, told
        to it (at most every few seconds) and logged."""
        if self.may_drive(client_id):
            return None
        source = self.source(client_id)
        why = (f"{source} may watch, not {what}: only a client that connects with the "
               "token (ws://HOST:PORT/?token=...) through omnican's port may"
               if self.settings.token is not None else
               f"{source} may watch, not {what}: it did not connect through omnican's port")
        if self._throttle.log(logging.WARNING, ("watcher", client_id), "%s", why):
            self._status("Warning", why, _STATUS_REFUSED)
        return why

    # ------------------------------------------------------------ the server's set-up

    def server_options(self, foxglove: Any) -> dict[str, Any]:
        """``foxglove.start_server`` arguments: capabilities, encodings, listener, services."""
        from foxglove.websocket import Capability

        return {"capabilities": [Capability.ClientPublish, Capability.Services,
                                 Capability.Parameters],
                "supported_encodings": list(ENCODINGS), "server_listener": self,
                "services": self._services(foxglove)}

    def attach(self, server: Any) -> None:
        from foxglove.websocket import StatusLevel

        self._server, self._status_level = server, StatusLevel

    def close(self) -> None:
        """From here on nothing reaches the base (the server is stopping)."""
        self._closed = True

    def _status(self, level: str, message: str, status_id: str) -> None:
        server = self._server
        if server is None or self._closed:
            return
        try:
            server.publish_status(message, getattr(self._status_level, level), status_id)
        except Exception as exc:  # a stopped server: nothing to tell
            logger.debug("Foxglove status not sent: %s", exc)

    def _clear_refusals(self) -> None:
        if self._server is not None and not self._closed:
            try:
                self._server.remove_status([_STATUS_REFUSED])
            except Exception as exc:
                logger.debug("Foxglove status not removed: %s", exc)

    # ------------------------------------------------------------ client channels

    def on_client_advertise(self, client: Any, channel: Any) -> None:
        if channel.topic.startswith(GRANT_PREFIX):
            key = channel.topic[len(GRANT_PREFIX):]
            with self._lock:
                vouched = key in self._grants
                self._grants.discard(key)
                if vouched:
                    self._drivers.add(client.id)
            if not vouched:
                self._throttle.log(logging.WARNING, ("grant", client.id), "%s: a key the "
                                   "relay did not give: it may only watch",
                                   self.source(client.id))
            return
        with self._lock:
            self._channels[(client.id, channel.id)] = _Channel(
                channel.topic, channel.encoding, channel.schema_name)
        if channel.topic == self.settings.cmd_vel_topic:
            logger.info("%s advertises %s (%s, %s)", self.source(client.id), channel.topic,
                        quote(channel.schema_name), quote(channel.encoding))

    def on_client_unadvertise(self, client: Any, client_channel_id: int) -> None:
        """A channel ends: unadvertised, or its client left (the SDK unadvertises every
        channel of a client that disconnects). The controller's last control channel
        gone: the base stops at once, and control is free."""
        topic = self.settings.cmd_vel_topic
        with self._lock:
            if client_channel_id == GRANT_CHANNEL_ID:
                self._drivers.discard(client.id)  # it left
            gone = self._channels.pop((client.id, client_channel_id), None)
            still = any(c.topic == topic for (cid, _), c in self._channels.items()
                        if cid == client.id)
        if gone is None or gone.topic != topic or still:
            return
        source = self.source(client.id)
        # The base stops at once, inside the release: no one else's command between.
        if self.commands(source).release(stop=not self._closed) and not self._closed:
            logger.warning("%s left while driving: the base stops", source)
            self._status("Warning", f"{source} left while driving: the base stopped; "
                         "the next client to publish drives", _STATUS_DRIVER)
            with self._lock:
                self._told.clear()
                self._driver = None

    def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
        with self._lock:
            channel = self._channels.get((client.id, client_channel_id))
        if channel is None or channel.topic != self.settings.cmd_vel_topic or self._closed:
            return
        if self.watcher(client.id, "drive"):
            self.refused += 1
            return
        source = self.source(client.id)
        commands = self.commands(source)
        try:
            twist = decode_twist(channel.encoding, channel.schema_name, data)
            # The base checks the values (Chassis.set_twist: beyond sense, refused).
            sent = commands.drive(twist)
        except ValueError as exc:
            self.refused += 1
            mine = commands.may(Action.DRIVE).ok  # the driver's (or it could drive now)
            if mine:
                commands.stop()  # the controller sends what cannot be obeyed: stop
            what = "the base stops" if mine else "ignored"
            if self._throttle.log(logging.WARNING, ("bad", source), "%s: a %s message that "
                                  "is not a usable Twist (%s): %s", source, channel.topic,
                                  exc, what):
                self._status("Warning", f"{source}: {channel.topic}: {exc}: {what}",
                             _STATUS_REFUSED)
            return
        holder = sent.refused_by
        if holder is not None:
            self.refused += 1
            with self._lock:
                first = source not in self._told
                self._told.add(source)
            if first:
                wait = f"{commands.timeout_s:g} s"
                if commands.stopped_by() == holder:
                    logger.info("%s: stopped by %s; its commands are ignored until it lets "
                                "go", source, holder)
                    text = (f"{holder} stopped the base: {source}'s commands are ignored "
                            f"until it sends none for {wait}")
                else:
                    logger.info("%s: %s is driving; its commands are ignored", source, holder)
                    text = (f"{holder} is driving the base: {source}'s commands are ignored "
                            f"until it stops (for {wait}) or leaves")
                self._status("Warning", text, _STATUS_REFUSED)
            return
        self.twists += 1
        with self._lock:
            changed, self._driver = self._driver != source, source
            if changed:
                self._told.clear()
        if changed:
            logger.info("%s drives the base", source)
            self._clear_refusals()
            self._status("Info", f"{source} drives the base", _STATUS_DRIVER)

    # the rest of the SDK's listener: nothing to do
    def on_subscribe(self, client: Any, channel: Any) -> None:
        pass

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        pass

    def on_parameters_subscribe(self, param_names: list[str]) -> None:
        pass

    def on_parameters_unsubscribe(self, param_names: list[str]) -> None:
        pass

    def on_connection_graph_subscribe(self) -> None:
        pass

    def on_connection_graph_unsubscribe(self) -> None:
        pass

    def on_playback_control_request(self, request: Any) -> None:
        return None

    # ------------------------------------------------------------ parameters

    def _parameter(self, name: str) -> Any:
        from foxglove.websocket import Parameter, ParameterType

        cfg = self.base.cfg
        key = name.split(".", 1)[1]
        value = getattr(cfg.chassis, key)
        if math.isinf(value):  # JSON has no inf (the protocol would say null): the top speed
            linear, angular = top_speeds(cfg.limits(), cfg.kinematics())
            value = linear if key == "max_speed" else angular
        return Parameter(name, value=float(value), type=ParameterType.Float64)

    def on_get_parameters(self, client: Any, param_names: list[str],
                          request_id: str | None = None) -> list[Any]:
        names = [n for n in param_names if n in PARAMETERS] if param_names else PARAMETERS
        return [self._parameter(n) for n in names]

    def on_set_parameters(self, client: Any, parameters: list[Any],
                          request_id: str | None = None) -> list[Any]:
        source = self.source(client.id)
        if self.watcher(client.id, "change a parameter"):
            return [self._parameter(p.name) for p in parameters if p.name in PARAMETERS]
        commands = self.commands(source)
        names = []
        for p in parameters:
            name = p.name
            if name not in PARAMETERS:
                self._status("Warning", f"{source}: no parameter {quote(name)} (the "
                             f"parameters: {', '.join(PARAMETERS)})", "omnican.parameters")
                continue
            names.append(name)
            old = getattr(self.base.cfg.chassis, name.split(".", 1)[1])
            value, reason = _set_limit(commands, name, p.get_value(), self._closed)
            if reason is not None:
                logger.warning("%s: refused %s = %s: %s", source, name, quote(p.get_value()),
                               reason)
                self._status("Warning", f"{source}: refused {reason}; {name} stays {old:g}",
                             "omnican.parameters")
                continue
            logger.info("%s set %s = %g", source, name, value)
            self._status("Info", f"{source} set {name} = {value:g}", "omnican.parameters")
        return [self._parameter(n) for n in names]


def _set_limit(commands: CommandSource, name: str, raw: Any, closed: bool
               ) -> tuple[float, str | None]:
    """Set the parameter ``name`` to ``raw`` through a client's ``commands``: its value,
    and why it was refused (None: it was set)."""
    if closed:
        return math.nan, f"{name}: the base is closing"
    try:
        value = parameter_value(name, raw)
    except ValueError as exc:
        return math.nan, str(exc).removeprefix("live: ")
    answer = commands.set_limits(**{name.split(".", 1)[1]: value})
    if answer.refused_by is not None:
        return value, f"{name}: {answer.refused_by} is driving; only it may change a limit now"
    return value, None if answer.failed is None else answer.failed.removeprefix("live: ")
