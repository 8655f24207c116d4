"""What a commissioning master does on the bus besides LSS (:mod:`omnican.analysis.commission`,
:mod:`omnican.analysis.parameters`): watch for another master, ask the nodes for their
identity (1018h) with SDO clients of its own, and wait for a reset node's boot-up."""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Sequence

import canopen
from canopen.sdo.client import SdoClient
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican.protocol.cia301 import HEARTBEAT_BASE, IDENTITY, NMT_COB_ID, SYNC_COB_ID

LSS_MASTER_COB_ID = 0x7E5
LSS_SLAVE_COB_ID = 0x7E4
BOOT_WAIT_S = 3.0  # a reset drive's boot-up, at most

Identity = tuple[int, int, int, int]  # vendor, product, revision, serial
#: Frames only a master sends, and what they are called in the one line that names them.
_FOREIGN = {NMT_COB_ID: "NMT commands (000h)", SYNC_COB_ID: "SYNC (080h: a base running)",
            LSS_MASTER_COB_ID: "LSS requests (7E5h)"}


class MasterWatch:
    """Notes the frames of another master (LSS requests, NMT commands, SYNC: a base
    running; this process's own sends are not received) and counts the LSS answers, on
    the Notifier thread."""

    def __init__(self, network: canopen.Network) -> None:
        self.network = network
        self.foreign: set[int] = set()  # the COB-IDs of another master's frames seen
        self.answers = 0
        self.boots: dict[int, float] = {}
        self._watched: set[int] = set()
        self._lock = threading.Lock()
        network.subscribe(LSS_MASTER_COB_ID, self._foreign)
        network.subscribe(NMT_COB_ID, self._foreign)
        network.subscribe(SYNC_COB_ID, self._foreign)
        network.subscribe(LSS_SLAVE_COB_ID, self._answer)

    def _foreign(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            self.foreign.add(can_id)

    def _answer(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            self.answers += 1

    def _boot(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if data[:1] == b"\x00":
            with self._lock:
                self.boots[can_id - HEARTBEAT_BASE] = time.monotonic()

    def watch_boot(self, node_id: int) -> None:
        if node_id not in self._watched:
            self._watched.add(node_id)
            self.network.subscribe(HEARTBEAT_BASE + node_id, self._boot)

    def another_master(self) -> str | None:
        with self._lock:
            seen = sorted(set(self.foreign))
        if not seen:
            return None
        what = " and ".join(_FOREIGN[c] for c in seen)
        return (f"another master is on the bus ({what} this command did not send): "
                "commission with the bus to yourself")

    def close(self) -> None:
        for cob, handler in [(c, self._foreign) for c in _FOREIGN] + [
                (LSS_SLAVE_COB_ID, self._answer)] + [
                (HEARTBEAT_BASE + n, self._boot) for n in sorted(self._watched)]:
            if handler in self.network.subscribers.get(cob, []):
                self.network.unsubscribe(cob, handler)


def identities(network: canopen.Network, sdo_timeout_s: float,
                node_ids: Sequence[int] | None = None) -> dict[int, Identity]:
    """Node id -> identity (1018h sub 1-4) of the nodes that answer SDO (all node ids
    when ``node_ids`` is None: canopen's scanner asks each for 1000h)."""
    if node_ids is None:
        network.scanner.reset()
        network.scanner.search()
        time.sleep(max(0.3, sdo_timeout_s))
        node_ids = sorted(network.scanner.nodes)
    out: dict[int, Identity] = {}
    for node_id in node_ids:
        values = read_identity(network, node_id, sdo_timeout_s)
        if values is not None:
            out[node_id] = values
    return out


def read_identity(network: canopen.Network, node_id: int,
                   sdo_timeout_s: float) -> Identity | None:
    client = sdo_client(network, node_id, sdo_timeout_s)
    try:
        values = [struct.unpack("<I", client.upload(IDENTITY, sub)[:4])[0] for sub in range(1, 5)]
    except (SdoAbortedError, SdoCommunicationError, struct.error):
        return None
    finally:
        network.unsubscribe(client.tx_cobid, client.on_response)
    return (values[0], values[1], values[2], values[3])


def sdo_client(network: canopen.Network, node_id: int, timeout_s: float) -> SdoClient:
    from canopen import objectdictionary as od

    client = SdoClient(0x600 + node_id, 0x580 + node_id, od.ObjectDictionary())
    client.network = network
    client.RESPONSE_TIMEOUT = timeout_s
    network.subscribe(client.tx_cobid, client.on_response)
    return client


def wait_boot(watch: MasterWatch, node_id: int, sent: float) -> bool:
    deadline = sent + BOOT_WAIT_S
    while time.monotonic() < deadline:
        if watch.boots.get(node_id, 0) >= sent:
            return True
        time.sleep(0.02)
    return False
