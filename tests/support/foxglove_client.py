"""A minimal Foxglove WebSocket client for the tests: connects, subscribes to topics by
name, and hands back (topic, log time, payload).

It offers both names of the protocol: ``foxglove.websocket.v1`` (the ws-protocol
specification, spoken by foxglove-sdk up to its 0.1x releases and by foxglove_bridge) and
``foxglove.sdk.v1`` (what newer foxglove-sdk servers accept); the message framing used
here (JSON control messages, binary MessageData with opcode 1) is the same in both."""

from __future__ import annotations

import json
import struct
import time
from collections.abc import Iterable, Iterator
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01


class FoxgloveClient:
    def __init__(self, url: str, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while True:
            try:
                self.ws: ClientConnection = connect(
                    url, subprotocols=SUBPROTOCOLS,  # type: ignore[arg-type]
                    open_timeout=2.0, max_size=None).__enter__()
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)
        self.channels: dict[str, dict[str, Any]] = {}
        self._subs: dict[int, str] = {}
        self.server_info: dict[str, Any] = {}

    def _handle_text(self, text: str) -> None:
        msg = json.loads(text)
        if msg.get("op") == "serverInfo":
            self.server_info = msg
        elif msg.get("op") == "advertise":
            for ch in msg["channels"]:
                self.channels[ch["topic"]] = ch

    def wait_for_topics(self, topics: Iterable[str], timeout: float = 10.0) -> None:
        wanted = set(topics)
        deadline = time.monotonic() + timeout
        while not wanted <= set(self.channels):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f"not advertised: {sorted(wanted - set(self.channels))}")
            data = self.ws.recv(timeout=remaining)
            if isinstance(data, str):
                self._handle_text(data)

    def subscribe(self, topics: Iterable[str]) -> None:
        subs = []
        for topic in topics:
            sub_id = len(self._subs) + 1
            self._subs[sub_id] = topic
            subs.append({"id": sub_id, "channelId": self.channels[topic]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def messages(self, timeout: float) -> Iterator[tuple[str, int, bytes]]:
        deadline = time.monotonic() + timeout
        while (remaining := deadline - time.monotonic()) > 0:
            try:
                data = self.ws.recv(timeout=remaining)
            except (TimeoutError, ConnectionClosed):  # quiet, or the server stopped
                return
            if isinstance(data, str):
                self._handle_text(data)
                continue
            if data[0] == MESSAGE_DATA:
                sub_id, log_time = struct.unpack_from("<IQ", data, 1)
                yield self._subs[sub_id], log_time, bytes(data[13:])

    def close(self) -> None:
        self.ws.close()
