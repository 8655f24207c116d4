"""The live view's front door: the port Foxglove connects to, relayed to the SDK's server.

foxglove-sdk's server (every release on PyPI, 0.5.0 to 0.30.3 at least) accepts only the
WebSocket subprotocol ``foxglove.sdk.v1`` and answers HTTP 400 to a client that offers
only ``foxglove.websocket.v1``: Foxglove Studio 1.x, Lichtblick up to 1.21, PlotJuggler,
and ``@foxglove/ws-protocol``'s own examples. Both names stand for the same protocol (the
same JSON and binary messages), so this relay lets either in: it reads the client's
opening request, offers the SDK ``foxglove.sdk.v1`` in its place, and gives the client
back the name it asked for. After the handshake it copies bytes both ways untouched.

A client offering neither name is answered 400 here, and a browser opening the address
as a page (a phone accepting the certificate) gets one line saying what it is.

It also terminates TLS (``wss://``) when given a certificate, so the SDK's server itself
stays plain on loopback, where only this relay connects to it. One thread runs every
connection (asyncio); it never touches the base.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import ssl
import threading
from pathlib import Path

logger = logging.getLogger(__name__)

SDK_SUBPROTOCOL = "foxglove.sdk.v1"
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
_HEAD_LIMIT = 64 * 1024  # an opening request larger than this is not a browser's
_HEAD_TIMEOUT_S = 10.0
_CHUNK = 256 * 1024


def tls_context(cert: Path, key: Path) -> ssl.SSLContext:
    """A server-side TLS context from PEM files; ValueError naming what is wrong."""
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    try:
        ctx.load_cert_chain(str(cert), str(key))
    except (OSError, ssl.SSLError) as exc:
        why = getattr(exc, "reason", None) or getattr(exc, "strerror", None) or str(exc)
        raise ValueError(f"cannot use {cert} / {key} for TLS: {why}") from None
    return ctx


def offered_subprotocols(head: bytes) -> list[str]:
    """The subprotocols an HTTP upgrade request offers, in order."""
    out: list[str] = []
    for line in head.split(b"\r\n")[1:]:
        name, sep, value = line.partition(b":")
        if sep and name.strip().lower() == b"sec-websocket-protocol":
            out += [p.strip() for p in value.decode("latin-1").split(",") if p.strip()]
    return out


def rewrite_protocol(head: bytes, protocol: str) -> bytes:
    """``head`` (an HTTP request or response head) with its Sec-WebSocket-Protocol
    header(s) replaced by one naming ``protocol``."""
    lines = head.split(b"\r\n")
    kept = [lines[0]]
    placed = False
    for line in lines[1:]:
        name, sep, _ = line.partition(b":")
        if sep and name.strip().lower() == b"sec-websocket-protocol":
            if not placed:
                kept.append(b"Sec-WebSocket-Protocol: " + protocol.encode("latin-1"))
                placed = True
            continue
        kept.append(line)
    return b"\r\n".join(kept)


def _header(head: bytes, name: bytes) -> str:
    for line in head.split(b"\r\n")[1:]:
        key, sep, value = line.partition(b":")
        if sep and key.strip().lower() == name:
            return value.decode("latin-1").strip()
    return ""


def _answer(status: str, text: str) -> bytes:
    body = text.encode()
    return (f"HTTP/1.1 {status}\r\nContent-Type: text/plain; charset=utf-8\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n").encode() + body


#: What a browser is told when it opens the address as a page (a phone accepting the
#: certificate first, say): this is the live view, and how to reach it.
PAGE = ("omnican's live view for Foxglove. In Foxglove: Open connection -> Foxglove "
        "WebSocket -> this address with ws:// (or wss:// with TLS) instead of http(s)://.\n")


async def _read_head(reader: asyncio.StreamReader) -> bytes:
    """An HTTP head, up to and including its blank line."""
    return await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), _HEAD_TIMEOUT_S)


async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(_CHUNK):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError, asyncio.IncompleteReadError):
        pass
    finally:
        with contextlib.suppress(Exception):
            if writer.can_write_eof():
                writer.write_eof()
            else:
                writer.close()


class Relay:
    """Listens on ``host:port`` (``port`` 0: any free port) and relays every connection
    to the SDK's server on 127.0.0.1:``upstream_port``. A context manager."""

    def __init__(self, host: str, port: int, upstream_port: int,
                 tls: ssl.SSLContext | None = None) -> None:
        self.upstream_port = upstream_port
        self._tls = tls
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
            sock.listen(64)
        except OSError:
            sock.close()
            raise
        sock.setblocking(False)
        self._sock = sock
        self.port: int = sock.getsockname()[1]
        self._loop = asyncio.new_event_loop()
        self._started = threading.Event()
        self._tasks: set[asyncio.Task[None]] = set()
        self._server: asyncio.Server | None = None
        self._thread = threading.Thread(target=self._run, name="omnican-foxglove-relay",
                                        daemon=True)
        self._thread.start()
        self._started.wait(5.0)

    # ------------------------------------------------------------ the loop thread

    def _run(self) -> None:
        loop = self._loop
        asyncio.set_event_loop(loop)
        try:
            self._server = loop.run_until_complete(asyncio.start_server(
                self._serve, sock=self._sock, ssl=self._tls,
                ssl_handshake_timeout=_HEAD_TIMEOUT_S if self._tls else None))
            self._started.set()
            loop.run_forever()
        finally:
            self._started.set()
            with contextlib.suppress(Exception):
                loop.run_until_complete(loop.shutdown_asyncgens())
            loop.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        if task is not None:
            self._tasks.add(task)
        peer = writer.get_extra_info("peername")
        who = f"{peer[0]}:{peer[1]}" if peer else "?"
        up_writer: asyncio.StreamWriter | None = None
        try:
            head = await _read_head(reader)
            offered = offered_subprotocols(head)
            answer = None
            if _header(head, b"upgrade").lower() != "websocket":
                writer.write(_answer("200 OK", PAGE))  # a browser, not Foxglove
                await writer.drain()
                return
            if SDK_SUBPROTOCOL not in offered and LEGACY_SUBPROTOCOL in offered:
                head, answer = rewrite_protocol(head, SDK_SUBPROTOCOL), LEGACY_SUBPROTOCOL
            elif SDK_SUBPROTOCOL not in offered:
                logger.info("Foxglove connection from %s refused: it offers %s, not %s or %s",
                            who, ", ".join(offered) or "no subprotocol", SDK_SUBPROTOCOL,
                            LEGACY_SUBPROTOCOL)
                writer.write(_answer("400 Bad Request", f"this is a Foxglove WebSocket "
                                     f"server: offer the subprotocol {SDK_SUBPROTOCOL} or "
                                     f"{LEGACY_SUBPROTOCOL}\n"))
                await writer.drain()
                return
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1",
                                                                 self.upstream_port)
            for w in (writer, up_writer):
                sock = w.get_extra_info("socket")
                if sock is not None:  # small messages (a Teleop command) go at once
                    with contextlib.suppress(OSError):
                        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            up_writer.write(head)
            await up_writer.drain()
            response = await _read_head(up_reader)
            if answer is not None:
                response = rewrite_protocol(response, answer)
            writer.write(response)
            await writer.drain()
            if response.split(b" ", 2)[1:2] == [b"101"]:
                logger.info("Foxglove viewer %s connected (%s)", who,
                            answer or SDK_SUBPROTOCOL)
            await asyncio.gather(_pump(reader, up_writer), _pump(up_reader, writer))
        except (asyncio.TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError,
                ConnectionError, OSError, ssl.SSLError) as exc:
            logger.debug("Foxglove connection from %s ended: %s", who, exc)
        except asyncio.CancelledError:
            pass
        finally:
            writer.close()
            if up_writer is not None:
                up_writer.close()
            if task is not None:
                self._tasks.discard(task)

    async def _shutdown(self) -> None:
        if self._server is not None:
            self._server.close()
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.wait(list(self._tasks), timeout=2.0)
        if self._server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 2.0)

    # ------------------------------------------------------------ any thread

    def close(self) -> None:
        """Stop listening and drop every connection. Idempotent."""
        if not self._thread.is_alive():
            self._sock.close()
            return
        loop = self._loop
        with contextlib.suppress(RuntimeError):
            asyncio.run_coroutine_threadsafe(self._shutdown(), loop).result(5.0)
        with contextlib.suppress(RuntimeError):
            loop.call_soon_threadsafe(loop.stop)
        self._thread.join(5.0)
        self._sock.close()

    def __enter__(self) -> Relay:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
