"""A Foxglove client that subscribes to every channel and then reads slowly, or never:
``python -m tests.support.stalled_foxglove_client URL [READ_EVERY_S]`` (0 or none: never).
It prints ``subscribed N`` once its subscriptions are sent, then holds the connection
until killed, reading one message every READ_EVERY_S seconds: the server's sends pile
up behind it. No keep-alive pings (a client that does not read would miss their
answers and close)."""

from __future__ import annotations

import json
import sys
import time

from websockets.sync.client import ClientConnection, connect

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def opened(url: str, timeout: float = 30.0) -> ClientConnection:
    deadline = time.monotonic() + timeout
    while True:
        try:
            return connect(url, subprotocols=SUBPROTOCOLS,  # type: ignore[arg-type]
                           open_timeout=5.0, max_size=None, ping_interval=None,
                           max_queue=4).__enter__()
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def subscribe_all(ws: ClientConnection, settle_s: float = 1.0) -> int:
    """Subscribe to every channel advertised until no more come for ``settle_s``."""
    channels: dict[str, int] = {}
    quiet_until = time.monotonic() + settle_s
    while time.monotonic() < quiet_until or not channels:
        try:
            data = ws.recv(timeout=settle_s)
        except TimeoutError:
            continue
        if isinstance(data, str):
            msg = json.loads(data)
            if msg.get("op") == "advertise":
                channels.update({c["topic"]: c["id"] for c in msg["channels"]})
                quiet_until = time.monotonic() + settle_s
    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i + 1, "channelId": cid} for i, cid in enumerate(channels.values())]}))
    return len(channels)


def main(argv: list[str]) -> None:
    url = argv[0]
    read_every = float(argv[1]) if len(argv) > 1 else 0.0
    ws = opened(url)
    print(f"subscribed {subscribe_all(ws)}", flush=True)
    while True:
        if read_every <= 0:
            time.sleep(3600)
            continue
        time.sleep(read_every)
        try:
            ws.recv(timeout=1.0)
        except TimeoutError:
            pass


if __name__ == "__main__":
    main(sys.argv[1:])
