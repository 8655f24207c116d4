"""A stranger on the Zenoh network, for the fleet view's tests and bench: a raw
eclipse-zenoh session (a client of a router on loopback, multicast off) that declares
what it is told: thousands of liveliness tokens that announce a base, a base of its own
whose summaries carry what it likes, a queryable on a real base's service.

As a process: ``python -m tests.zenoh.hostile ENDPOINT [--tokens N] [--evil]`` declares
N fake base tokens (``/fake<i>/omnican``, no summary) and, with --evil, the bases of
:func:`evil`; ``--router``: a Zenoh router listening on ENDPOINT instead. It prints
``ready`` and runs until stdin closes.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from typing import Any

from omnican.zenoh import rmw
from omnican.zenoh.services import service_key, trigger_response

STRING = "std_msgs/msg/String"
#: What a terminal obeys: clear the screen, set the window title, ring.
ESCAPES = "\x1b[2J\x1b]0;PWNED\x07"


def session_of(endpoint: str) -> Any:
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def summary_of(node: str, **fields: Any) -> dict[str, Any]:
    """A base's summary as omnican's bridge writes it, with ``fields`` changed."""
    out: dict[str, Any] = {
        "node": node, "state": "RUNNING", "stopped_reason": "", "enabled": True,
        "estop": False, "pose": {"x": 1.0, "y": 2.0, "theta": 0.5},
        "speed": {"vx": 0.0, "vy": 0.0, "wz": 0.0}, "faults": [], "stamp": time.time(),
        "period_s": 0.5}
    out.update(fields)
    return out


class FakeBase:
    """A base of the stranger's own: its summary publisher's token (its session's id,
    or ``zid``), a publisher whose summaries carry the GID that token gives."""

    def __init__(self, session: Any, namespace: str, node: str = "omnican",
                 zid: str | None = None, node_id: int = 0) -> None:
        self.node = rmw.RosNode(0, zid or str(session.info.zid()), node_id, node,
                             namespace=namespace)
        self.name = rmw.fully_qualified(namespace, node)
        topic = rmw.fully_qualified(namespace, "base_summary")
        hash_ = rmw.type_hash(STRING)
        self.token_key = self.node.endpoint_token(1, rmw.Kind.PUBLISHER, topic, STRING,
                                                  hash_, rmw.Qos())
        self.gid = rmw.gid_of(self.token_key)
        self._token = session.liveliness().declare_token(self.token_key)
        self._pub = session.declare_publisher(rmw.data_key(0, topic, STRING, hash_))
        self._seq = 0
        self._queryables: list[Any] = []
        self._session = session

    def publish(self, text: str | bytes | dict[str, Any]) -> None:
        """One summary: a dict as JSON (NaN written as JSON cannot), or the text as is."""
        from omnican.zenoh.bridge import string_cdr

        if isinstance(text, dict):
            text = json.dumps(text)
        data = text.encode() if isinstance(text, str) else text
        self._seq += 1
        self._pub.put(string_cdr(data), attachment=rmw.Attachment(
            self._seq, time.time_ns(), self.gid).encode())

    def serve(self, service: str, answer: Callable[[Any], None]) -> None:
        """A complete queryable on its ``service`` key, answered by ``answer(query)``."""
        self._queryables.append(self._session.declare_queryable(
            service_key(self.node, service), answer, complete=True))

    def close(self) -> None:
        for q in self._queryables:
            q.undeclare()
        self._pub.undeclare()
        self._token.undeclare()


def rogue(session: Any, node: rmw.RosNode, service: str,
          answer: Callable[[Any], None]) -> Any:
    """A complete queryable of ``session`` on another node's service key."""
    return session.declare_queryable(service_key(node, service), answer, complete=True)


def reply_trigger(query: Any, success: bool, message: str) -> None:
    """Answer a Trigger request as a base would (its sequence and GID echoed)."""
    asked = rmw.Attachment.decode(query.attachment.to_bytes())
    query.reply(query.key_expr, trigger_response(success, message),
                attachment=rmw.Attachment(asked.sequence, time.time_ns(), asked.gid).encode())


def fake_tokens(session: Any, count: int, prefix: str = "fake") -> list[Any]:
    """``count`` tokens that announce a base (``/<prefix><i>/omnican``) and nothing else."""
    zid = str(session.info.zid())
    hash_ = rmw.type_hash(STRING)
    out = []
    for i in range(count):
        node = rmw.RosNode(0, zid, i, "omnican", namespace=f"/{prefix}{i}")
        out.append(session.liveliness().declare_token(node.endpoint_token(
            1, rmw.Kind.PUBLISHER, f"/{prefix}{i}/base_summary", STRING, hash_, rmw.Qos())))
    return out


def evil(session: Any) -> list[FakeBase]:
    """Bases whose every text is an escape sequence, whose summary has NaN in it, and
    one whose name is one: what a terminal must never obey, and JSON never carry."""
    loud = FakeBase(session, "/loud")
    loud.serve("stop", lambda q: q.reply_err(f"{ESCAPES}rogue error".encode()))
    nan = FakeBase(session, "/nan")
    nan.serve("stop", lambda q: reply_trigger(q, True, f"stopped{ESCAPES}"))
    named = FakeBase(session, f"/evil{ESCAPES}")
    return [loud, nan, named]


def publish_evil(bases: list[FakeBase]) -> None:
    loud, nan, named = bases
    loud.publish(summary_of(loud.name, stopped_reason=f"stopped{ESCAPES}",
                            driver=f"a driver{ESCAPES}", faults=[f"wheel 1: {ESCAPES}"]))
    nan.publish(json.dumps(summary_of(nan.name, speed={"vx": float("nan"), "vy": 0.0,
                                                       "wz": float("inf")})))
    named.publish(summary_of(named.name))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("endpoint")
    parser.add_argument("--tokens", type=int, default=0)
    parser.add_argument("--evil", action="store_true")
    parser.add_argument("--router", action="store_true")
    args = parser.parse_args()
    if args.router:
        from omnican.zenoh.bridge import open_session
        from omnican.zenoh.settings import ZenohSettings

        router = open_session(ZenohSettings(mode="router", listen=(args.endpoint,)))
        print("ready", flush=True)
        sys.stdin.read()
        router.close()
        return
    session = session_of(args.endpoint)
    try:
        tokens = fake_tokens(session, args.tokens)
        bases = evil(session) if args.evil else []
        print("ready", flush=True)
        import select

        while True:  # summaries twice a second, until stdin closes
            if bases:
                publish_evil(bases)
            if select.select([sys.stdin], [], [], 0.5)[0] and not sys.stdin.readline():
                break
        for base in bases:
            base.close()
        for token in tokens:
            token.undeclare()
    finally:
        session.close()


if __name__ == "__main__":
    main()
