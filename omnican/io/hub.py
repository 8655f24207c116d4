"""A loopback-only CAN hub, so programs in other processes share one simulated bus.

python-can's ``virtual`` bus only reaches buses of the same process. The hub runs
python-can-remote's server on 127.0.0.1 in front of a virtual channel: the
simulated drives sit on that channel in this process, and other processes connect
with ``interface = "remote"``, ``channel = "ws://127.0.0.1:<port>/"``.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

from omnican.errors import BusError, ConfigError

logger = logging.getLogger(__name__)

DEFAULT_PORT = 54701


def _check_loopback(host: str) -> None:
    try:
        addresses = {str(info[4][0]) for info in socket.getaddrinfo(host, None)}
    except socket.gaierror as exc:
        raise ConfigError(f"cannot resolve hub host {host!r}: {exc}") from None
    for addr in addresses:
        if not ipaddress.ip_address(addr.split("%")[0]).is_loopback:
            raise ConfigError(f"the hub serves loopback only; {host!r} is {addr}")


def _handler_class(on_thread: Callable[[], object] | None = None) -> type:
    """python-can-remote's request handler, with a client that vanishes (killed, or its
    socket gone) ending its session quietly and releasing its bus instead of dying
    with a BrokenPipeError traceback in the server thread."""
    from can_remote.server import ClientRequestHandler, RemoteServerProtocol
    from can_remote.websocket import WebSocket, get_accept_key

    class Protocol(RemoteServerProtocol):  # type: ignore[misc]
        def _send_to_client(self) -> None:
            if on_thread is not None:  # this session's thread that relays the bus
                on_thread()
            try:
                super()._send_to_client()
            except OSError as exc:
                logger.info("hub client went away: %s", exc)
                self.running = False
                self.bus.shutdown()

        def terminate(self, exc: BaseException) -> None:
            # A client killed mid-session (kill -9) resets its socket: there is no one
            # to send the close frame to, and trying chained two more tracebacks on it.
            if isinstance(exc, OSError):
                logger.info("hub client went away: %s", exc)
                return
            try:
                super().terminate(exc)
            except OSError as gone:
                logger.info("hub client went away: %s (%s)", gone, exc)

    class Handler(ClientRequestHandler):  # type: ignore[misc]
        def start_websocket(self) -> None:
            if on_thread is not None:  # this session's thread that relays the client
                on_thread()
            self.send_response(101)
            self.send_header("Upgrade", "WebSocket")
            self.send_header("Connection", "Upgrade")
            self.send_header("Sec-WebSocket-Accept",
                             get_accept_key(self.headers["Sec-WebSocket-Key"]))
            offered = [p.strip() for p in
                       self.headers.get("Sec-WebSocket-Protocol", "can.json.v1").split(",")]
            proto = "can.binary+json.v1" if "can.binary+json.v1" in offered else "can.json.v1"
            self.send_header("Sec-WebSocket-Protocol", proto)
            self.end_headers()
            session = Protocol(self.server.config, WebSocket(None, proto, sock=self.request))
            self.server.clients.append(session)
            try:
                session.run()
            finally:
                self.server.clients.remove(session)
                if session.bus is not None:
                    session.bus.shutdown()

    return Handler


class LoopbackHub:
    """Serves virtual channel ``channel`` on ``ws://host:port/`` (host must be loopback).

    A context manager; ``port=0`` picks a free port (see :attr:`url`). ``on_thread()`` is
    called first on each thread that relays a client's frames (``omnican sim`` gives them
    its drives' real-time priority: every frame between drives and host passes them)."""

    def __init__(self, channel: str, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 on_thread: Callable[[], object] | None = None) -> None:
        _check_loopback(host)
        try:
            from can_remote.server import RemoteServer
        except ImportError:
            raise ConfigError("serving the simulator to other processes needs python-can-remote "
                              "(pip install python-can-remote)") from None
        self.channel = channel
        config: dict[str, Any] = {"interface": "virtual", "channel": channel}
        logging.getLogger("can_remote").setLevel(logging.WARNING)
        try:
            self._server = RemoteServer(host, port, **config)
        except OSError as exc:  # the port is taken: a run-time failure, not bad usage
            raise BusError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        self._server.RequestHandlerClass = _handler_class(on_thread)
        self.host = host
        self.port = int(self._server.server_address[1])
        self._thread = threading.Thread(target=self._server.serve_forever, name="omnican-hub",
                                        kwargs={"poll_interval": 0.1}, daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}/"

    @property
    def bus_config(self) -> dict[str, Any]:
        """``can.Bus`` arguments for a client in another process."""
        return {"interface": "remote", "channel": self.url}

    @property
    def clients(self) -> int:
        return len(self._server.clients)

    def close(self, wait_clients_s: float = 2.0) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(timeout=2.0)
        # Hang up on every client: its bus goes away now, so it says the bus went down
        # rather than, a moment later, that the drives fell silent.
        for session in list(self._server.clients):
            session.running = False
            with contextlib.suppress(OSError):
                session._ws.close(1001, "the hub closed")
        # Client handlers end when their peers hang up; give them a moment.
        deadline = time.monotonic() + wait_clients_s
        while self._server.clients and time.monotonic() < deadline:
            time.sleep(0.02)

    def __enter__(self) -> LoopbackHub:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
