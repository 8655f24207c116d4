"""The services Foxglove clients may call when control is on (JSON; Foxglove's Service
Call panel), for :class:`omnican.live.control.Control`: ``/omnican/stop`` (anyone, at
any time; from another client it also takes control from the driver until it lets go),
``/omnican/recover``, ``/omnican/reset_odometry`` (to zero, or ``{"x", "y", "theta"}``),
and under simulation ``/omnican/sim/console`` (the fault console's commands:
``{"command": "fault 2"}``). Each answers ``{"success", "message"}``. While one client
drives, only it may call any but the stop: the base's to say (each client a command
source of the base's, :mod:`omnican.chassis.actions`); a service only words the answer.
"""

from __future__ import annotations

import json
import logging
from typing import Any, Protocol

from omnican.chassis.actions import Action, Outcome
from omnican.chassis.arbiter import CommandSource
from omnican.core.odometry import Pose2D
from omnican.errors import quote
from omnican.live.requests import REQUEST_LIMIT, check_size, number, read_json

logger = logging.getLogger(__name__)

SERVICE_STOP, SERVICE_RECOVER = "/omnican/stop", "/omnican/recover"
SERVICE_RESET, SERVICE_CONSOLE = "/omnican/reset_odometry", "/omnican/sim/console"
_CONSOLE_LINE_MAX = 200

_OBJECT = '{"type": "object"}'
_REPLY = ('{"type": "object", "properties": {"success": {"type": "boolean"}, '
          '"message": {"type": "string"}}}')
_POSE = ('{"type": "object", "properties": {"x": {"type": "number"}, "y": {"type": '
         '"number"}, "theta": {"type": "number"}}}')
_COMMAND = ('{"type": "object", "properties": {"command": {"type": "string"}}, '
            '"required": ["command"]}')


class Clients(Protocol):
    """What the services ask of the Foxglove clients' control they serve
    (:class:`omnican.live.control.Control`): who a client is, whether it may drive at
    all (the relay vouched for it), its command source, the base and the simulator."""

    base: Any
    sim: Any

    @property
    def closed(self) -> bool: ...

    def watcher(self, client_id: int, what: str) -> str | None: ...

    def source(self, client_id: int) -> str: ...

    def commands(self, source: str) -> CommandSource: ...

    def driver_stopped(self, driver: str) -> None: ...


class Services:
    """The services of ``control``: who a caller is and whether it may drive at all is
    its to say, what it may do now the base's (its command source's answers); they act
    on its base and simulator."""

    def __init__(self, control: Clients) -> None:
        self.control = control
        self.base = control.base
        self.sim = control.sim

    def build(self, foxglove: Any) -> list[Any]:
        """The SDK's services (``foxglove``: the SDK's module)."""
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
            refused = self.control.watcher(request.client_id, f"call {name}")
            if refused:
                raise ValueError(refused)
            if request.encoding != "json":
                raise ValueError(f"{name} takes JSON, got {quote(request.encoding)}")
            check_size(request.payload, REQUEST_LIMIT, f"{name}: a request")
            payload = bytes(request.payload)
            body = read_json(payload) if payload.strip() else {}
            if not isinstance(body, dict):
                raise ValueError(f"{name} takes a JSON object, got {quote(body)}")
            source = self.control.source(request.client_id)
            if self.control.closed:
                ok, message = False, "the base is closing"
            else:
                ok, message = fn(source, body)
            (logger.info if ok else logger.warning)("%s called %s: %s", source, name, message)
            return json.dumps({"success": ok, "message": message}).encode()
        return handle

    @staticmethod
    def _refused(answer: Outcome) -> str:
        """The answer's refusal or failure, in the services' words."""
        if answer.refused_by is not None:
            return (f"{answer.refused_by} is driving; only it may do this now (anyone may "
                    "call /omnican/stop)")
        return answer.failed or ""

    def _stop(self, source: str, body: dict[str, Any]) -> tuple[bool, str]:
        driver = self.control.commands(source).stop()
        if driver is None:
            return True, "stopping"
        self.control.driver_stopped(driver)
        return True, f"stopping; {driver} drives again once it has let go"

    def _recover(self, source: str, body: dict[str, Any]) -> tuple[bool, str]:
        answer = self.control.commands(source).recover()
        if answer.refused_by is not None:
            return False, self._refused(answer)
        if answer.failed is not None:
            return False, f"recover failed: {answer.failed}"
        return True, "recovered: every drive enabled"

    def _reset(self, source: str, body: dict[str, Any]) -> tuple[bool, str]:
        unknown = sorted(set(body) - {"x", "y", "theta"})
        if unknown:
            return False, f"unknown field {quote(unknown[0])} (x, y, theta)"
        try:
            pose = Pose2D(*(number(body.get(k, 0.0), k) for k in ("x", "y", "theta")))
        except ValueError as exc:
            return False, str(exc)
        answer = self.control.commands(source).reset_pose(pose)  # refuses one beyond sense
        if not answer.ok:
            return False, self._refused(answer)
        return True, f"odometry reset to x={pose.x:g} y={pose.y:g} theta={pose.theta:g}"

    def _console(self, source: str, body: dict[str, Any]) -> tuple[bool, str]:
        from omnican.sim import console

        line = body.get("command")
        if not isinstance(line, str) or not line.strip():
            return False, 'give a console command: {"command": "fault 2"} (help lists them)'
        if len(line) > _CONSOLE_LINE_MAX:
            return False, f"a console command of {len(line)} characters: too long"
        if line.split()[0].lower() in ("quit", "exit"):
            return False, "quit is the terminal's: not from Foxglove"
        replies: list[str] = []
        answer = self.control.commands(source).act(
            Action.SIM_CONSOLE, lambda: replies.append(console.command(self.sim, line) or ""))
        if not answer.ok:
            return False, self._refused(answer)
        return not replies[0].startswith("error:"), replies[0]
