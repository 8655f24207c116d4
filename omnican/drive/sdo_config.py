"""SDO configuration: what a node is set to in PRE-OPERATIONAL, by expedited SDO, and
what the way out undoes.

:meth:`SdoConfig.configure` (blocking, bounded; after the boot-up and the PDOs): the mode
of operation (read back from 6061h), the ramps, the rated current (for the current in A),
the ``[[wheel.sdo]]`` writes, the heartbeat producer (1017h) and consumer
(1016h, watching this host), the abort connection option (6007h).
:meth:`SdoConfig.stop` disables what the loop could not and clears the consumer.

:class:`SdoTransfers`: each transfer of a node's configuration, a failure one
:class:`DriveError` naming the node, what it was doing and why (an abort's code in words,
no answer, an answer slower than ``chassis.sdo_timeout_s``); the PDO configuration
(:mod:`omnican.drive.pdo_config`) writes through it too.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from typing import TYPE_CHECKING

import can
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican.drive.power_state import StageDriver
from omnican.drive.sdo_client import SdoTooSlowError
from omnican.errors import DriveError
from omnican.protocol import cia402, heartbeat
from omnican.protocol.cia301 import (
    CONSUMER_HEARTBEAT_TIME,
    PRODUCER_HEARTBEAT_TIME,
    NmtState,
    abort_text,
)
from omnican.protocol.cia402 import Command, Mode, State
from omnican.protocol.object_map import Entry, Obj, obj_name

if TYPE_CHECKING:
    from omnican.drive.configurable import ConfigurableNode

logger = logging.getLogger("omnican.drive")

# Power stages with no torque: nothing to disable on the way out.
_OFF_STATES = frozenset({State.SWITCH_ON_DISABLED, State.NOT_READY_TO_SWITCH_ON, State.FAULT})
MODE_READS, MODE_READ_GAP_S = 4, 0.05  # the mode display read back after setting the mode


class SdoTransfers:
    """SDO downloads (and the errors of any transfer) of one node's configuration."""

    def __init__(self, node: ConfigurableNode) -> None:
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


class SdoConfig:
    """What one node is set to by SDO in PRE-OPERATIONAL, and its undoing on the way out."""

    def __init__(self, node: ConfigurableNode, sdo: SdoTransfers) -> None:
        self.node = node
        self._sdo = sdo
        #: warnings of a configuration, said at its end (once the answers were all one
        #: device's: a second device on this id garbles SDO replies)
        self.later: list[str] = []
        #: The drive watches this host's heartbeat (1016h written since its last reset
        #: communication, which clears it): then the way out stops that.
        self.watching = False

    def configure(self, warn: list[str] | None = None) -> None:
        """Mode, ramps, rated currents, the [[wheel.sdo]] writes, heartbeats, 6007h. Blocking,
        bounded; raises DriveError naming the node and what it was doing."""
        node = self.node
        s = node.settings
        self.later = []
        for stage in node.stages:
            stage.forget()
            if stage.mode is not None:
                self._sdo.write_value(stage.mode, int(node.mode), f"mode {node.mode.short}")
            self._confirm_mode(stage)
        self._configure_ramps()
        self._read_rated_currents()
        for write in node.layout.sdo_writes:  # [[wheel.sdo]]
            self._sdo.write(write.entry, write.entry.subindex, write.data,
                            f"{write.entry.name} from {write.origin}")
        self._sdo.write(PRODUCER_HEARTBEAT_TIME, 0, s.heartbeat_ms.to_bytes(2, "little"),
                        "heartbeat producer")
        # Its heartbeats are due from now on, not from its boot-up: the configuration
        # up to here may have taken many periods.
        node.heartbeat.producer_on(node.clock.now())
        if node.has_consumer:
            ms = heartbeat.consumer_time_ms(s.heartbeat_ms, s.heartbeat_timeout_factor)
            value = (s.host_node_id << 16) | ms
            self.watching = True  # also if the write's answer is lost
            self._sdo.write(CONSUMER_HEARTBEAT_TIME, 1, value.to_bytes(4, "little"),
                            "heartbeat consumer")
            abort = node.axes[0].objs.get(Obj.ABORT_OPTION)
            if abort is not None:
                self._sdo.write_value(abort, cia402.ABORT_QUICK_STOP, "abort connection option")
        elif warn is not None:
            warn.append(f"node {node.node_id} ({node.eds_name}) has no heartbeat consumer (1016h):"
                        " it will not stop by itself if this host dies")

    def _confirm_mode(self, stage: StageDriver) -> None:
        """Read the mode display (6061h) back: a drive that did not take the mode (a
        read-only 6060h, a mode it refuses without an abort) would follow targets it
        does not read as velocities. A drive gets ``MODE_READS`` reads, 50 ms apart."""
        node = self.node
        display = stage.mode_display
        if display is None:
            return
        clock = node.clock
        value = None
        for read in range(MODE_READS):
            if read and clock.can_wait:
                clock.sleep(MODE_READ_GAP_S)
            with self._sdo.errors(f"reading the mode display ({display.address})"):
                value = display.decode(node.remote.sdo.upload(display.index, display.subindex))
            if value == int(node.mode):
                return
        assert value is not None
        mode = stage.mode
        how = (f"writing mode {node.mode.short} ({int(node.mode)}) to {mode.address}"
               if mode is not None and mode.writable else
               f"setting mode {node.mode.short} ({int(node.mode)}), which its EDS does not "
               "let omnican write")
        raise DriveError(f"node {node.node_id}: the mode display {display.address} shows "
                         f"{value} ({cia402.MODE_NAMES.get(value, 'unknown')}) after {how}: "
                         "the drive did not take the mode")

    def _configure_ramps(self) -> None:
        """Drive ramps a little steeper than omnican's own limits, so they never lag them."""
        node = self.node
        s = node.settings
        radius = 0.5  # m; generous for a spin's share of a wheel's acceleration
        wheel_accel = 2.0 * (s.max_accel + radius * s.max_angular_accel)
        wheel_stop = 2.0 * (s.stop_decel + radius * s.stop_angular_decel)
        for ax in node.axes:
            scale = abs(ax.wheel.velocity_scale)
            if node.mode is Mode.VELOCITY:
                for rec, rate in ((Obj.VL_ACCEL, wheel_accel), (Obj.VL_DECEL, wheel_stop)):
                    index = ax.objs.record(rec)
                    if index is not None:
                        self._sdo.write(index, 1, round(rate * scale).to_bytes(4, "little"),
                                        "vl ramp delta speed")
                        self._sdo.write(index, 2, (1).to_bytes(2, "little"), "vl ramp delta time")
                continue
            for obj, rate in ((Obj.PROFILE_ACCEL, wheel_accel), (Obj.PROFILE_DECEL, wheel_stop),
                              (Obj.QUICK_STOP_DECEL, wheel_stop)):
                entry = ax.objs.get(obj)
                if entry is not None:
                    self._sdo.write_value(entry, round(rate * scale), obj_name(obj))

    def _read_rated_currents(self) -> None:
        """6078h counts per mille of the rated current (6075h, mA): read it, so the
        current is shown in A (where the config gives no scale of its own)."""
        node = self.node
        node.health.forget()
        for read in node.layout.health.reads:
            if read.quantity != "current" or read.scale is not None:
                continue
            axis = next(ax for ax in node.axes if ax.wheel_index == read.wheels[0])
            rated = axis.objs.get(Obj.RATED_CURRENT)
            if rated is None:
                logger.info("node %d: no rated current (6075h): the current is not shown in A",
                            node.node_id)
                continue
            try:
                raw = node.remote.sdo.upload(rated.index, rated.subindex)
            except SdoTooSlowError as exc:
                raise DriveError(self._sdo.too_slow(exc)) from None
            except (SdoAbortedError, SdoCommunicationError) as exc:
                self.later.append(f"node {node.node_id}: reading the rated current "
                                   f"({rated.address}) failed: {exc}")
                continue
            node.health.scales[read.key] = rated.decode(raw) / 1_000_000.0  # mA per mille

    def stop(self) -> None:
        """Disable any power stage not known to be off and stop watching the host
        (consumer off); best effort."""
        node = self.node
        # A bus that refuses frames (down, transmit queue full) must not turn the way
        # out into a traceback: the drives' heartbeat consumers stop them anyway.
        for stage in node.stages:
            # The loop's disable did not get there (it did not run, or not for long
            # enough); a STOPPED node answers no SDO (its 6007h reaction stopped it).
            if stage.state not in _OFF_STATES and node.nmt_state != NmtState.STOPPED:
                cw = stage.controlword
                off = cia402.apply_command(stage.cw, Command.DISABLE_VOLTAGE)
                try:
                    node.remote.sdo.download(cw.index, cw.subindex, cw.encode(off))
                    sw = stage.statusword  # what it is now, for the closing line
                    raw = node.remote.sdo.upload(sw.index, sw.subindex)
                    stage.statusword_value = sw.decode(raw) & 0xFFFF
                except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
                    logger.warning("node %d: disabling its drive by SDO failed: %s",
                                   node.node_id, exc)
        if node.has_consumer and self.watching:
            try:
                node.remote.sdo.download(CONSUMER_HEARTBEAT_TIME, 1, b"\x00\x00\x00\x00")
            except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
                logger.debug("node %d: clearing the heartbeat consumer failed: %s", node.node_id,
                             exc)
