"""Configuring a node over SDO, and the way out.

:meth:`NodeSetup.configure` (blocking, bounded, on the opening thread or a
re-configuration worker): NMT reset communication and the boot-up (asked again when
lost), the PDO plan of :mod:`omnican.plan.pdo` (or, for a drive that refuses it, its own
mapping, restored by another reset communication; objects that mapping lacks go by
expedited SDO every cycle), mode, ramps, heartbeat producer and consumer, 6007h, then
NMT OPERATIONAL. Two devices answering as one node are refused before the start.
:meth:`NodeSetup.stop` disables what the loop could not, clears the consumer and leaves
OPERATIONAL.

One concern a module: the boot-up and two devices on one id in :mod:`omnican.drive.boot`,
the PDOs in :mod:`omnican.drive.pdo_setup`, the SDO transfers and their errors in
:mod:`omnican.drive.setup_sdo`; the order they run in, the mode, ramps and heartbeats here.
"""

from __future__ import annotations

import logging
import threading
from typing import Any, Protocol

import can
import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican.clock import Clock
from omnican.config import ChassisSettings
from omnican.drive.boot import counting_sdo_answers, reset_communication
from omnican.drive.cyclic import AxisIO
from omnican.drive.health import NodeHealth
from omnican.drive.pdo_setup import PdoSetup
from omnican.drive.sdoclient import SdoTooSlowError
from omnican.drive.setup_sdo import SetupSdo
from omnican.drive.stage import StageDriver
from omnican.errors import DriveError
from omnican.plan.health import HealthPlan
from omnican.plan.node import NodeLayout
from omnican.plan.pdo import NodePlan
from omnican.protocol import cia402, heartbeat
from omnican.protocol.cia301 import (
    CONSUMER_HEARTBEAT_TIME,
    NMT_COB_ID,
    PRODUCER_HEARTBEAT_TIME,
    NmtCommand,
    NmtState,
)
from omnican.protocol.cia402 import Command, Mode, State
from omnican.protocol.heartbeat import HeartbeatWatch
from omnican.protocol.object_map import Obj, obj_name


class Node(Protocol):
    """What the configuration needs of a node (:class:`omnican.drive.DriveNode`)."""

    node_id: int
    network: canopen.Network
    remote: canopen.RemoteNode
    settings: ChassisSettings
    layout: NodeLayout
    dictionary: Any
    eds_name: str
    mode: Mode
    has_consumer: bool
    clock: Clock
    stages: list[StageDriver]
    axes: list[AxisIO]
    nmt_state: int | None
    seen_operational: bool
    twins: bool
    boot_count: int
    configured_boot: int
    _boot_seen: threading.Condition

    health: NodeHealth
    heartbeat: HeartbeatWatch

    def use_plan(self, plan: NodePlan) -> None: ...

    def use_health(self, plan: HealthPlan) -> None: ...


logger = logging.getLogger("omnican.drive")

# Power stages with no torque: nothing to disable on the way out.
_OFF_STATES = frozenset({State.SWITCH_ON_DISABLED, State.NOT_READY_TO_SWITCH_ON, State.FAULT})
MODE_READS, MODE_READ_GAP_S = 4, 0.05  # the mode display read back after setting the mode


class NodeSetup:
    """The SDO side of one node: its configuration and its way out."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self._sdo = SetupSdo(node)
        #: the PDOs: the plan, or the drive's own mapping (it keeps why it refused the plan)
        self._pdos = PdoSetup(node, self._sdo, self._reset_communication)
        self._later: list[str] = []  # warnings of a configuration, logged at its end
        # The drive watches this host's heartbeat (1016h written since its last reset
        # communication, which clears it): then the way out stops that.
        self._watching = False

    def configure(self, warn: list[str] | None = None) -> None:
        """Reset communication, configure in PRE-OPERATIONAL, start. Blocking, bounded.

        Raises DriveError naming the node and what it was doing; also when two devices
        answer as this node (each boot-up and SDO answer comes twice), before it starts."""
        node = self.node
        self._later = []
        with counting_sdo_answers(node):
            self._configure(warn)
        # What failed on the way, said once the answers were all one device's (a second
        # device on this id garbles SDO replies: then its error is the only one).
        for text in self._later:
            logger.warning("%s", text)
        node.network.send_message(NMT_COB_ID, bytes([NmtCommand.START, node.node_id]))

    def _configure(self, warn: list[str] | None) -> None:
        node = self.node
        s = node.settings
        node.seen_operational = False
        self._reset_communication()
        # PDOs first: a drive that refuses the plan is reset once more to get its own
        # mapping back, which also resets what is set below in 1000h-1FFFh (1016h, 1017h).
        self._pdos.configure(warn)
        for stage in node.stages:
            stage.forget()
            if stage.mode is not None:
                self._sdo.write_value(stage.mode, int(node.mode), f"mode {node.mode.short}")
            self._confirm_mode(stage)
        self._configure_ramps()
        self._read_rated_currents()
        for write in node.layout.settings_writes:  # [[wheel.sdo]]
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
            self._watching = True  # also if the write's answer is lost
            self._sdo.write(CONSUMER_HEARTBEAT_TIME, 1, value.to_bytes(4, "little"),
                            "heartbeat consumer")
            abort = node.axes[0].objs.get(Obj.ABORT_OPTION)
            if abort is not None:
                self._sdo.write_value(abort, cia402.ABORT_QUICK_STOP, "abort connection option")
        elif warn is not None:
            warn.append(f"node {node.node_id} ({node.eds_name}) has no heartbeat consumer (1016h):"
                        " it will not stop by itself if this host dies")
        for ax in node.axes:
            ax.reseed()
            ax.raw, ax.epoch = None, -1
        self._pdos.drop_canopen_handlers()

    def _reset_communication(self) -> None:
        """NMT reset communication and the boot-up (:mod:`omnican.drive.boot`)."""

        def cleared() -> None:
            self._watching = False  # a reset communication clears 1016h
            self.node.heartbeat.producer_off()  # and puts 1017h back to its power-on value

        reset_communication(self.node, cleared)

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
                self._later.append(f"node {node.node_id}: reading the rated current "
                                   f"({rated.address}) failed: {exc}")
                continue
            node.health.scales[read.key] = rated.decode(raw) / 1_000_000.0  # mA per mille

    def stop(self) -> None:
        """Disable any power stage not known to be off, stop watching the host (consumer
        off) and leave OPERATIONAL; best effort."""
        node = self.node
        # A bus that refuses frames (down, transmit queue full) must not turn the way
        # out into a traceback: the drives' heartbeat consumers stop them anyway.
        if not node.boot_count or node.twins:
            return  # never heard, or two devices answering as one: nothing was enabled
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
        if node.has_consumer and self._watching:
            try:
                node.remote.sdo.download(CONSUMER_HEARTBEAT_TIME, 1, b"\x00\x00\x00\x00")
            except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
                logger.debug("node %d: clearing the heartbeat consumer failed: %s", node.node_id,
                             exc)
        try:
            node.network.send_message(NMT_COB_ID,
                                      bytes([NmtCommand.ENTER_PRE_OPERATIONAL, node.node_id]))
        except (can.CanError, OSError, RuntimeError) as exc:
            logger.debug("node %d: NMT pre-operational not sent: %s", node.node_id, exc)
