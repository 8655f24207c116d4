"""The SDO transfers of a node's configuration, each failure one :class:`DriveError`
naming the node, what it was doing and why (an abort's code in words, no answer, an
answer slower than ``chassis.sdo_timeout_s``).

Shared by :class:`omnican.drive.setup.NodeSetup` and :class:`omnican.drive.pdo_setup.PdoSetup`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import TYPE_CHECKING

from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican.drive.sdoclient import SdoTooSlowError
from omnican.errors import DriveError
from omnican.protocol.cia301 import abort_text
from omnican.protocol.object_map import Entry

if TYPE_CHECKING:
    from omnican.drive.setup import Node


class SetupSdo:
    """SDO downloads (and the errors of any transfer) of one node's configuration."""

    def __init__(self, node: Node) -> None:
        self.node = node

    @contextlib.contextmanager
    def errors(self, doing: str) -> Iterator[None]:
        """SDO failures as one DriveError naming the node, what it was doing and why."""
        node = self.node
        try:
            yield
        except SdoAbortedError as exc:
            raise DriveError(f"node {node.node_id}: {doing} refused: {abort_text(exc.code)}"
                             ) from None
        except SdoTooSlowError as exc:
            raise DriveError(self.too_slow(exc)) from None
        except SdoCommunicationError:
            sdo = node.remote.sdo
            wait = node.settings.sdo_timeout_s if not node.clock.lockstep else 0.0
            raise DriveError(f"node {node.node_id}: no SDO answer {doing} ({sdo.MAX_RETRIES} "
                             f"attempts{f', {wait:g} s each' if wait else ''})") from None

    def too_slow(self, exc: SdoTooSlowError) -> str:
        timeout = self.node.settings.sdo_timeout_s
        return (f"node {self.node.node_id} answers SDOs after {exc.late_s:.2f} s, slower than "
                f"chassis.sdo_timeout_s {timeout:g} s: raise it")

    def write(self, entry_or_index: Entry | int, subindex: int, data: bytes,
              what: str) -> None:
        node = self.node
        index = entry_or_index.index if isinstance(entry_or_index, Entry) else entry_or_index
        with self.errors(f"writing {what} (0x{index:04X}:{subindex:02X})"):
            node.remote.sdo.download(index, subindex, data)

    def write_value(self, entry: Entry, value: int, what: str) -> None:
        if entry.writable:
            self.write(entry, entry.subindex, entry.encode(value), what)

