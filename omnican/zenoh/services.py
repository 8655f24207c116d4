"""The base's services on Zenoh, in rmw_zenoh's request/reply form: ``~/stop``,
``~/recover`` and ``~/reset_odometry``, each a ``std_srvs/srv/Trigger``.

rmw_zenoh maps a service server to a queryable on the service's data key; a client's
request is a query whose payload is the request's CDR and whose attachment carries the
client's sequence number and GID; the reply carries the response's CDR and an attachment
with the same sequence number and GID (that is how the client matches it). A service
server also declares a liveliness token of kind ``SS``.

Requests are queued and answered from the bridge's poll, not in Zenoh's threads: a
recover takes as long as the drives take to enable, and a lock-step base runs only when
its clock is stepped. Anyone may stop the base (a stop is not a command), and the stop
holds until ``~/recover`` (:meth:`~omnican.chassis.Chassis.halt`): a remote operator's
stop must not end when the next cmd_vel arrives. Recover and reset odometry are refused
while another source drives it. Who may do what is the base's to say (each caller a
command source of the base's, :mod:`omnican.chassis.actions`); a service only words the
answer.
"""

from __future__ import annotations

import logging
import struct
import time
from collections.abc import Callable
from typing import Any

from omnican.chassis.actions import Outcome
from omnican.chassis.arbiter import CommandSource
from omnican.errors import quote
from omnican.zenoh import rmw

logger = logging.getLogger(__name__)

TRIGGER = "std_srvs/srv/Trigger"
SERVICES = ("stop", "recover", "reset_odometry")
QUEUE = 16  # requests kept between polls (a flood of requests costs the oldest)
SOURCE = "Zenoh service client"  # a caller the others are told of: SOURCE <its GID>
_CDR_LE = b"\x00\x01\x00\x00"


def trigger_response(success: bool, message: str) -> bytes:
    """CDR (little endian, with its header) of a std_srvs/srv/Trigger_Response."""
    text = message.encode("utf-8", "replace") + b"\x00"
    return _CDR_LE + struct.pack("<?3xI", success, len(text)) + text


#: CDR (with its header) of a std_srvs/srv/Trigger_Request: an empty struct is one byte.
TRIGGER_REQUEST = _CDR_LE + b"\x00"


def read_trigger_response(data: bytes) -> tuple[bool, str]:
    """(success, message) of a Trigger_Response's CDR (little or big endian); ValueError
    for bytes that are not one (the inverse of :func:`trigger_response`)."""
    if len(data) < 12 or data[0] != 0 or data[1] not in (0, 1):
        raise ValueError(f"not a CDR Trigger response ({len(data)} bytes)")
    order = "<" if data[1] == 1 else ">"
    success, size = struct.unpack_from(f"{order}?3xI", data, 4)
    text = data[12:12 + size]
    if size == 0 or len(text) != size or text[-1] != 0:
        raise ValueError(f"not a CDR Trigger response (a {size}-byte string in "
                         f"{len(data) - 12} bytes)")
    return success, text[:-1].decode("utf-8", "replace")


def trigger_hash() -> str:
    return rmw.service_type_hash(TRIGGER, "", "bool success\nstring message")


def service_key(node: rmw.RosNode, name: str) -> str:
    """The data key of the node's service ``name`` (``~/name``)."""
    fq = rmw.fully_qualified(node.namespace, f"{node.name}/{name}")
    return f"{node.domain_id}/{fq[1:]}/{rmw.dds_type_name(TRIGGER)}/{trigger_hash()}"


class Services:
    """The queryables and tokens of :data:`SERVICES` on ``session`` for ``node``; call
    :meth:`poll` to answer what arrived."""

    def __init__(self, session: Any, node: rmw.RosNode, caller: Callable[[bytes], CommandSource],
                 first_entity_id: int) -> None:
        import zenoh

        self.caller = caller  # the base's command source of a request's GID
        self.answered = 0
        self._queryables: dict[str, Any] = {}
        self._tokens: list[Any] = []
        for n, name in enumerate(SERVICES):
            fq = rmw.fully_qualified(node.namespace, f"{node.name}/{name}")
            # complete: it answers every request on its key (rmw_zenoh's servers say so,
            # and its clients ask only complete queryables)
            self._queryables[name] = session.declare_queryable(
                service_key(node, name), zenoh.handlers.FifoChannel(QUEUE), complete=True)
            self._tokens.append(session.liveliness().declare_token(node.endpoint_token(
                first_entity_id + n, rmw.Kind.SERVICE, fq, TRIGGER, trigger_hash(),
                rmw.Qos())))
        self._actions: dict[str, Callable[[CommandSource], tuple[bool, str]]] = {
            "stop": self._stop, "recover": self._recover, "reset_odometry": self._reset}

    def poll(self) -> None:
        for name, queryable in self._queryables.items():
            for _ in range(QUEUE):
                query = queryable.try_recv()
                if query is None:
                    break
                self._answer(name, query)

    def _answer(self, name: str, query: Any) -> None:
        raw = query.attachment
        try:
            asked = rmw.Attachment.decode(raw.to_bytes() if raw is not None else b"")
        except ValueError:
            query.reply_err("an rmw_zenoh request carries an attachment (sequence, GID)")
            return
        source = self.caller(asked.gid)
        ok, message = self._actions[name](source)
        logger.info("%s: %s from %s: %s", name, "done" if ok else "refused", source.name,
                    message)
        reply = rmw.Attachment(asked.sequence, time.time_ns(), asked.gid)
        query.reply(query.key_expr, trigger_response(ok, message), attachment=reply.encode())
        self.answered += 1

    @staticmethod
    def _stop(source: CommandSource) -> tuple[bool, str]:
        """A stop held until ``~/recover``: whoever drove loses control, and no command
        (theirs or another's) moves the base until then."""
        answer = source.halt(f"stopped by {source.name}")
        if not answer.ok:
            return False, quote(answer.why, 200)
        return True, "stopped: held until recover"

    def _recover(self, source: CommandSource) -> tuple[bool, str]:
        return self._said(source.recover(), "recovered")

    def _reset(self, source: CommandSource) -> tuple[bool, str]:
        return self._said(source.reset_pose(), "odometry reset to (0, 0, 0)")

    @staticmethod
    def _said(answer: Outcome, done: str) -> tuple[bool, str]:
        """A service's reply to the base's answer: ``done``, who drives, or what failed."""
        if answer.refused_by is not None:
            return False, f"{answer.refused_by} is driving the base"
        if answer.failed is not None:
            return False, quote(answer.failed, 200)
        return True, done

    def close(self) -> None:
        for queryable in self._queryables.values():
            queryable.undeclare()
        for token in self._tokens:
            token.undeclare()
        self._queryables.clear()
        self._tokens.clear()
