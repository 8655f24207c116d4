"""Driving from Foxglove: what clients of the live view may send the base, when control
is on (``--foxglove-control``).

- **Twists** on the control topic (``/cmd_vel``; Foxglove's Teleop panel), as JSON or CDR,
  ``geometry_msgs/Twist`` or ``TwistStamped``: each goes to :meth:`Chassis.set_velocity`,
  so the same limits and watchdog apply as to every other command. One controller at a
  time (the base's :meth:`~omnican.chassis.Chassis.command_source`, each client one
  source; shared with the front end's other sources): the first client that publishes holds
  control until it leaves or sends nothing for ``cmd_timeout_s``; another client's
  commands are ignored and a status message says who is driving. The base stops at once
  when the controlling client leaves. A Twist that cannot be read (NaN, a wrong type)
  moves nothing; from the controller it stops the base.
- **Services** (JSON; Foxglove's Service Call panel): ``/omnican/stop`` (anyone, at any
  time; from another client it also takes control from the driver until it lets go),
  ``/omnican/recover``, ``/omnican/reset_odometry`` (to zero, or ``{"x", "y",
  "theta"}``), and under simulation ``/omnican/sim/console`` (the fault console's
  commands: ``{"command": "fault 2"}``). Each answers ``{"success", "message"}``.
- **Parameters** named as the config's keys (``chassis.max_speed``, ...; the limits of
  :data:`omnican.config.LIVE_LIMITS`), read and set live through
  :meth:`Chassis.set_limits` (the config's checks); a refused value keeps the old one and
  a status message gives the reason. An unlimited speed (inf in the config) reads as the
  top speed the base can reach under its other limits (:func:`omnican.core.limits.top_speeds`:
  the wheel limit's), a number; set back, it is a limit at that speed, which changes
  nothing the base does.

While one client drives, only it may recover, reset odometry, change a parameter or
inject a fault. The SDK calls these methods on its own threads; none of them blocks the
control loop.

Only a client the relay vouched for (:mod:`omnican.live.relay`: its web page allowed, the
token given when one is set) may do any of this; the others, and whoever reaches the SDK's
own port past the relay, may watch and read the parameters, nothing more. Every message is
measured before it is read (:data:`TWIST_LIMIT`, :data:`REQUEST_LIMIT`), a value quoted
back is cut short (:func:`omnican.errors.quote`), and JSON nested too deeply is refused as
any other junk is.
"""

from __future__ import annotations

import json
import logging
import math
import secrets
import threading
from dataclasses import dataclass
from typing import Any

from omnican.chassis.arbiter import CommandSource
from omnican.config import LIVE_LIMITS
from omnican.core.kinematics import Twist
from omnican.core.limits import top_speeds
from omnican.core.odometry import Pose2D
from omnican.errors import OmnicanError, quote
from omnican.live.relay import GRANT_CHANNEL_ID, GRANT_PREFIX
from omnican.live.settings import FoxgloveSettings
from omnican.log_throttle import Throttle

logger = logging.getLogger(__name__)

ENCODINGS = ["json", "cdr"]  # what clients may publish in; Foxglove picks the first
TWIST_TYPES = {"geometry_msgs/Twist": False, "geometry_msgs/msg/Twist": False,
               "geometry_msgs/TwistStamped": True, "geometry_msgs/msg/TwistStamped": True}
PARAMETERS = tuple(f"chassis.{key}" for key in LIVE_LIMITS)
SERVICE_STOP, SERVICE_RECOVER = "/omnican/stop", "/omnican/recover"
SERVICE_RESET, SERVICE_CONSOLE = "/omnican/reset_odometry", "/omnican/sim/console"
_STATUS_DRIVER, _STATUS_REFUSED = "omnican.control", "omnican.control.refused"
#: The largest Twist message read (a TwistStamped in JSON with a long frame id is a few
#: hundred bytes), and the largest service request (a console command, a pose).
TWIST_LIMIT = REQUEST_LIMIT = 4096
#: The longest parameter value read as text ("inf", "0.25").
PARAMETER_TEXT_LIMIT = 64
_CONSOLE_LINE_MAX = 200
_GRANTS_PENDING_MAX = 256  # keys given to the relay and not yet used (connections opening)

_OBJECT = '{"type": "object"}'
_REPLY = ('{"type": "object", "properties": {"success": {"type": "boolean"}, '
          '"message": {"type": "string"}}}')
_POSE = ('{"type": "object", "properties": {"x": {"type": "number"}, "y": {"type": '
         '"number"}, "theta": {"type": "number"}}}')
_COMMAND = ('{"type": "object", "properties": {"command": {"type": "string"}}, '
            '"required": ["command"]}')


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where} must be a number, got {quote(value)}")
    if not math.isfinite(value):
        raise ValueError(f"{where} must be finite, got {quote(value)}")
    return float(value)


def _reject_constant(word: str) -> Any:
    raise ValueError(f"not a finite number: {word}")


def _check_size(data: bytes, limit: int, what: str) -> None:
    if len(data) > limit:
        raise ValueError(f"{what} of {len(data)} bytes (at most {limit}): not read")


def _json(data: bytes) -> Any:
    """JSON as the protocol defines it: NaN and Infinity (which Python's json reads) are
    not numbers there. Nesting deeper than Python's recursion allows is refused."""
    try:
        return json.loads(bytes(data), parse_constant=_reject_constant)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"not JSON: {quote(str(exc), 80)}") from None
    except RecursionError:
        raise ValueError("not JSON this program reads: nested too deeply") from None


def decode_twist(encoding: str, schema_name: str, data: bytes) -> Twist:
    """The body twist (vx, vy, wz) of a ``geometry_msgs`` Twist or TwistStamped message
    in ``encoding`` (json or cdr). ValueError saying why it cannot be used: another type,
    another encoding, a field missing or not a finite number."""
    stamped = TWIST_TYPES.get(schema_name)
    if stamped is None:
        raise ValueError("want geometry_msgs/Twist, got "
                         f"{quote(schema_name) if schema_name else 'no schema name'}")
    _check_size(data, TWIST_LIMIT, "a message")
    typename = "geometry_msgs/msg/TwistStamped" if stamped else "geometry_msgs/msg/Twist"
    if encoding == "json":
        msg = _json(data)
    elif encoding == "cdr":
        from omnican.telemetry import cdr

        try:
            msg = cdr.decode(typename, bytes(data))
        except Exception as exc:  # rosbags says little of a short or damaged buffer
            raise ValueError(f"not a CDR {typename}: {type(exc).__name__}") from None
    else:
        raise ValueError(f"cannot read {quote(encoding)} messages (json or cdr)")
    if stamped:
        msg = msg.get("twist") if isinstance(msg, dict) else None
    if not isinstance(msg, dict):
        raise ValueError("want an object with linear and angular")
    parts = []
    for group, axis in (("linear", "x"), ("linear", "y"), ("angular", "z")):
        vector = msg.get(group, {})
        if not isinstance(vector, dict):
            raise ValueError(f"{group} must be an object, got {quote(vector)}")
        parts.append(_number(vector.get(axis, 0.0), f"{group}.{axis}"))
    return Twist(*parts)


def parameter_value(name: str, value: Any) -> float | int:
    """A parameter's new value as a limit: a number as it came, or "inf" (also numbers
    as text: the Parameters panel edits a text value as text). ValueError if neither."""
    if isinstance(value, str):
        if len(value) > PARAMETER_TEXT_LIMIT:
            raise ValueError(f"{name}: must be a number, got {quote(value)}")
        text = value.strip().lower()
        try:
            number = math.inf if text in ("inf", "infinity") else float(text)
        except ValueError:
            raise ValueError(f"{name}: must be a number, got {quote(value)}") from None
        if math.isnan(number):
            raise ValueError(f"{name}: must be a number, got {quote(value)}")
        return number
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name}: must be a number, got {quote(value)}")
    return value


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

    def _commands(self, source: str) -> CommandSource:
        """The base's handle for ``source``: every command and stop goes through it."""
        handle: CommandSource = self.base.command_source(source)
        return handle

    @property
    def timeout_s(self) -> float:
        """How long a silent driver keeps control (the base's command timeout)."""
        return self._commands("").timeout_s

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

    def _watcher(self, client_id: int, what: str) -> str | None:
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
        if self._commands(source).release(stop=not self._closed) and not self._closed:
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
        if self._watcher(client.id, "drive"):
            self.refused += 1
            return
        source = self.source(client.id)
        commands = self._commands(source)
        try:
            twist = decode_twist(channel.encoding, channel.schema_name, data)
            # The base checks the values (Chassis.set_twist: beyond sense, refused).
            holder = commands.send(twist)
        except ValueError as exc:
            self.refused += 1
            mine = commands.may_act() is None
            if mine:
                commands.stop()  # the controller sends what cannot be obeyed: stop
            what = "the base stops" if mine else "ignored"
            if self._throttle.log(logging.WARNING, ("bad", source), "%s: a %s message that "
                                  "is not a usable Twist (%s): %s", source, channel.topic,
                                  exc, what):
                self._status("Warning", f"{source}: {channel.topic}: {exc}: {what}",
                             _STATUS_REFUSED)
            return
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
        if self._watcher(client.id, "change a parameter"):
            return [self._parameter(p.name) for p in parameters if p.name in PARAMETERS]
        holder = self._commands(source).may_act()
        names = []
        for p in parameters:
            name = p.name
            if name not in PARAMETERS:
                self._status("Warning", f"{source}: no parameter {quote(name)} (the "
                             f"parameters: {', '.join(PARAMETERS)})", "omnican.parameters")
                continue
            names.append(name)
            old = getattr(self.base.cfg.chassis, name.split(".", 1)[1])
            try:
                if holder is not None:
                    raise ValueError(f"{name}: {holder} is driving; only it may change a "
                                     "limit now")
                if self._closed:
                    raise ValueError(f"{name}: the base is closing")
                value = parameter_value(name, p.get_value())
                self.base.set_limits(**{name.split(".", 1)[1]: value})
            except (ValueError, OmnicanError) as exc:
                reason = str(exc).removeprefix("live: ")
                logger.warning("%s: refused %s = %s: %s", source, name, quote(p.get_value()),
                               reason)
                self._status("Warning", f"{source}: refused {reason}; {name} stays {old:g}",
                             "omnican.parameters")
                continue
            logger.info("%s set %s = %g", source, name, value)
            self._status("Info", f"{source} set {name} = {value:g}", "omnican.parameters")
        return [self._parameter(n) for n in names]

    # ------------------------------------------------------------ services

    def _services(self, foxglove: Any) -> list[Any]:
        from foxglove.websocket import MessageSchema, Service, ServiceSchema

        def schema(name: str, text: str) -> Any:
            return MessageSchema(encoding="json", schema=foxglove.Schema(
                name=name, encoding="jsonschema", data=text.encode()))

        reply = schema("omnican.Reply", _REPLY)
        table = [(SERVICE_STOP, "omnican/Trigger", schema("omnican.Empty", _OBJECT), self._stop),
                 (SERVICE_RECOVER, "omnican/Trigger", schema("omnican.Empty", _OBJECT),
                  self._recover),
                 (SERVICE_RESET, "omnican/ResetOdometry", schema("omnican.Pose2D", _POSE),
                  self._reset)]
        if self.sim is not None:
            table.append((SERVICE_CONSOLE, "omnican/SimConsole",
                          schema("omnican.ConsoleCommand", _COMMAND), self._console))
        return [Service(name, schema=ServiceSchema(kind, request=request, response=reply),
                        handler=self._handler(name, fn)) for name, kind, request, fn in table]

    def service_names(self) -> list[str]:
        names = [SERVICE_STOP, SERVICE_RECOVER, SERVICE_RESET]
        return names + ([SERVICE_CONSOLE] if self.sim is not None else [])

    def _handler(self, name: str, fn: Any) -> Any:
        def handle(request: Any) -> bytes:
            # A ValueError is the SDK's failure answer to the caller, with its message.
            refused = self._watcher(request.client_id, f"call {name}")
            if refused:
                raise ValueError(refused)
            if request.encoding != "json":
                raise ValueError(f"{name} takes JSON, got {quote(request.encoding)}")
            _check_size(request.payload, REQUEST_LIMIT, f"{name}: a request")
            payload = bytes(request.payload)
            body = _json(payload) if payload.strip() else {}
            if not isinstance(body, dict):
                raise ValueError(f"{name} takes a JSON object, got {quote(body)}")
            source = self.source(request.client_id)
            if self._closed:
                ok, message = False, "the base is closing"
            else:
                ok, message = fn(source, body)
            (logger.info if ok else logger.warning)("%s called %s: %s", source, name, message)
            return json.dumps({"success": ok, "message": message}).encode()
        return handle

    def _refused(self, source: str) -> str | None:
        holder = self._commands(source).may_act()
        return None if holder is None else (f"{holder} is driving; only it may do this now "
                                            "(anyone may call /omnican/stop)")

    def _stop(self, source: str, body: dict[str, Any]) -> tuple[bool, str]:
        driver = self._commands(source).stop()
        if driver is None:
            return True, "stopping"
        with self._lock:
            self._told.discard(driver)  # it is told why, at its next command
            self._driver = None
        return True, f"stopping; {driver} drives again once it has let go"

    def _recover(self, source: str, body: dict[str, Any]) -> tuple[bool, str]:
        refused = self._refused(source)
        if refused:
            return False, refused
        try:
            self.base.recover()
        except OmnicanError as exc:
            return False, f"recover failed: {exc}"
        return True, "recovered: every drive enabled"

    def _reset(self, source: str, body: dict[str, Any]) -> tuple[bool, str]:
        refused = self._refused(source)
        if refused:
            return False, refused
        unknown = sorted(set(body) - {"x", "y", "theta"})
        if unknown:
            return False, f"unknown field {quote(unknown[0])} (x, y, theta)"
        try:
            pose = Pose2D(*(_number(body.get(k, 0.0), k) for k in ("x", "y", "theta")))
            self.base.reset_pose(pose)  # the base refuses a pose beyond sense
        except ValueError as exc:
            return False, str(exc)
        return True, f"odometry reset to x={pose.x:g} y={pose.y:g} theta={pose.theta:g}"

    def _console(self, source: str, body: dict[str, Any]) -> tuple[bool, str]:
        from omnican.sim import console

        refused = self._refused(source)
        if refused:
            return False, refused
        line = body.get("command")
        if not isinstance(line, str) or not line.strip():
            return False, 'give a console command: {"command": "fault 2"} (help lists them)'
        if len(line) > _CONSOLE_LINE_MAX:
            return False, f"a console command of {len(line)} characters: too long"
        if line.split()[0].lower() in ("quit", "exit"):
            return False, "quit is the terminal's: not from Foxglove"
        reply = console.command(self.sim, line) or ""
        return not reply.startswith("error:"), reply
