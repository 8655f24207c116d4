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

It is the door for whoever may come in. A browser's opening request names the web page
that opened it (``Origin``): one not allowed is answered 403, so no page the operator
happens to visit can reach the robot. A client that may drive (the token given, when one
is set) is vouched for to the server's listener: the relay's first message on its behalf
advertises a channel named by a one-time key the listener gave it (:data:`GRANT_PREFIX`),
which no client sees. A client without it, or one that reaches the SDK's own port past
this relay, may only watch. A client message larger than :data:`MESSAGE_LIMIT` ends the
connection before anything reads it: the relay counts frame lengths and never holds a
message.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import os
import socket
import ssl
import struct
import threading
from collections.abc import Callable
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from omnican.errors import quote
from omnican.log_throttle import Throttle

logger = logging.getLogger(__name__)

SDK_SUBPROTOCOL = "foxglove.sdk.v1"
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
_HEAD_LIMIT = 64 * 1024  # an opening request larger than this is not a browser's
_HEAD_TIMEOUT_S = 10.0
_CHUNK = 256 * 1024
#: The largest message a client may send (its frames' payloads added up): the protocol's
#: client messages (a subscription, a Twist, a service call, a parameter) are far smaller.
MESSAGE_LIMIT = 64 * 1024
#: The topic prefix of the channel by which the relay vouches for a client that may drive.
GRANT_PREFIX = "/omnican/grant/"
#: That channel's id: the top of the client's id space, which clients count up from 0 or 1.
GRANT_CHANNEL_ID = 0xFFFFFFFF


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


def _header_or_none(head: bytes, name: bytes) -> str | None:
    for line in head.split(b"\r\n")[1:]:
        key, sep, value = line.partition(b":")
        if sep and key.strip().lower() == name:
            return value.decode("latin-1").strip()
    return None


def given_token(head: bytes) -> str | None:
    """The token an opening request gives: ``?token=`` in its URL (what a browser, and so
    Foxglove's app, can send) or an ``Authorization: Bearer`` header (a program)."""
    target = head.split(b"\r\n", 1)[0].split(b" ")
    if len(target) >= 2:
        values = parse_qs(urlsplit(target[1].decode("latin-1")).query).get("token")
        if values:
            return values[0]
    auth = _header_or_none(head, b"authorization")
    if auth is not None and auth[:7].lower() == "bearer ":
        return auth[7:].strip()
    return None


def without_query(head: bytes) -> bytes:
    """``head`` with its request target's query (a token) left out."""
    first, sep, rest = head.partition(b"\r\n")
    parts = first.split(b" ")
    if len(parts) == 3:
        parts[1] = parts[1].split(b"?", 1)[0] or b"/"
    return b" ".join(parts) + sep + rest


def client_text_frame(text: str) -> bytes:
    """One masked WebSocket text frame, as a client sends it (RFC 6455 5.2)."""
    payload = text.encode()
    mask = os.urandom(4)
    n = len(payload)
    if n < 126:
        head = struct.pack("!BB", 0x81, 0x80 | n)
    elif n < 1 << 16:
        head = struct.pack("!BBH", 0x81, 0x80 | 126, n)
    else:
        head = struct.pack("!BBQ", 0x81, 0x80 | 127, n)
    return head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


def grant_frame(key: str) -> bytes:
    """The relay's advertisement that vouches for the connection it is sent on."""
    return client_text_frame(json.dumps({"op": "advertise", "channels": [{
        "id": GRANT_CHANNEL_ID, "topic": GRANT_PREFIX + key, "encoding": "json",
        "schemaName": "omnican/Grant"}]}))


class MessageTooLargeError(Exception):
    def __init__(self, size: int) -> None:
        super().__init__(f"a {size}-byte message (at most {MESSAGE_LIMIT})")
        self.size = size


async def _pump_frames(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                       limit: int = MESSAGE_LIMIT) -> None:
    """Copies a client's WebSocket frames to ``writer`` as they are, adding up each
    message's length from the frame headers: MessageTooLargeError (nothing of that frame
    sent on) when one would pass ``limit``."""
    message = 0
    try:
        while True:
            try:
                head = await reader.readexactly(2)
            except asyncio.IncompleteReadError:
                return
            opcode, length = head[0] & 0x0F, head[1] & 0x7F
            extra = b""
            if length == 126:
                extra = await reader.readexactly(2)
                length = struct.unpack("!H", extra)[0]
            elif length == 127:
                extra = await reader.readexactly(8)
                length = struct.unpack("!Q", extra)[0]
            if head[1] & 0x80:
                extra += await reader.readexactly(4)  # the mask key
            if opcode < 8:  # data (control frames stand alone and are at most 125 bytes)
                message = length if opcode != 0 else message + length
                if message > limit:
                    raise MessageTooLargeError(message)
            writer.write(head + extra)
            while length:
                data = await reader.read(min(length, _CHUNK))
                if not data:
                    return
                length -= len(data)
                writer.write(data)
                await writer.drain()
            await writer.drain()
    except (ConnectionError, OSError, asyncio.IncompleteReadError):
        pass
    finally:
        _end(writer)


def _end(writer: asyncio.StreamWriter) -> None:
    """Pass the end of one direction on: half-close where the transport can, else close."""
    with contextlib.suppress(Exception):
        if writer.can_write_eof():
            writer.write_eof()
        else:
            writer.close()


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
        _end(writer)


class Relay:
    """Listens on ``host:port`` (``port`` 0: any free port) and relays every connection
    to the SDK's server on 127.0.0.1:``upstream_port``. A context manager."""

    def __init__(self, host: str, port: int, upstream_port: int,
                 tls: ssl.SSLContext | None = None, *,
                 origin_allowed: Callable[[str | None], bool] = lambda origin: True,
                 token: str | None = None, grant: Callable[[], str] | None = None) -> None:
        """``origin_allowed(origin)``: whether a browser on that page may connect (None:
        no Origin). ``token``: what a client must give to drive (None: any may).
        ``grant()``: a one-time key the server's listener will take as the relay's word
        that the connection may drive (None: no one drives here)."""
        self.upstream_port = upstream_port
        self._tls = tls
        self._origin_allowed = origin_allowed
        self._token = token
        self._grant = grant
        self._throttle = Throttle(logger)
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
            origin = _header_or_none(head, b"origin")
            if not self._origin_allowed(origin):
                self._throttle.warning(("origin", who.rsplit(":", 1)[0]), "Foxglove "
                                       "connection from %s refused: a web page at %s, not "
                                       "one allowed ([foxglove] origins, --foxglove-origin)",
                                       who, quote(origin))
                writer.write(_answer("403 Forbidden", "this web page may not connect to the "
                                     "robot (omnican: [foxglove] origins)\n"))
                await writer.drain()
                return
            may_drive = self._grant is not None
            if self._token is not None and may_drive:
                token = given_token(head)
                if token is not None and not hmac.compare_digest(
                        token.encode("utf-8", "surrogateescape"), self._token.encode()):
                    self._throttle.warning(("token", who.rsplit(":", 1)[0]), "Foxglove "
                                           "connection from %s refused: a wrong token", who)
                    writer.write(_answer("403 Forbidden", "wrong token\n"))
                    await writer.drain()
                    return
                may_drive = token is not None
            head = without_query(head)
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
            if response.split(b" ", 2)[1:2] != [b"101"]:
                return
            if may_drive and self._grant is not None:
                up_writer.write(grant_frame(self._grant()))  # before anything of the client's
                await up_writer.drain()
            logger.info("Foxglove viewer %s connected (%s; %s)", who, answer or SDK_SUBPROTOCOL,
                        "may drive" if may_drive else
                        "watches only" if self._grant is not None else "watches")
            await asyncio.gather(_pump_frames(reader, up_writer), _pump(up_reader, writer))
        except MessageTooLargeError as exc:
            self._throttle.warning(("large", who.rsplit(":", 1)[0]), "Foxglove client %s "
                                   "sent %s: disconnected", who, exc)
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
