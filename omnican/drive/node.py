"""One CANopen node driving one or more wheels (axes), on a live network: what it is
made of, the order it is configured in, and what it tells (heartbeats, boot-ups, EMCYs).

A :class:`DriveNode` composes its power state machines (:mod:`omnican.drive.power_state`)
and its cyclic frames (:mod:`omnican.drive.cyclic`); :meth:`DriveNode.configure` runs NMT
and boot (:mod:`omnican.drive.nmt`), the PDO configuration
(:mod:`omnican.drive.pdo_config`) and the SDO configuration
(:mod:`omnican.drive.sdo_config`) in the order CiA 301 has them. Frame handlers run on the
receiving thread and only copy values; the control loop calls
:attr:`DriveNode.cyclic_frames` and :attr:`DriveNode.controlword_frame` once a cycle.

Units: m/s at the rim <-> drive velocity units (``velocity_scale``); encoder counts
-> continuous metres of travel across counter wrap-around and drive reboots.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence

import can
import canopen
from canopen.emcy import EmcyError

from omnican.clock import REAL_TIME, Clock
from omnican.drive import nmt
from omnican.drive.cyclic import AxisIO, CyclicIO, EpochSource, SdoCounts
from omnican.drive.health import NodeHealth
from omnican.drive.pdo_config import PdoConfig
from omnican.drive.power_state import StageDriver
from omnican.drive.sdo_client import CheckedRemoteNode
from omnican.drive.sdo_config import SdoConfig, SdoTransfers
from omnican.log_throttle import Throttle
from omnican.plan.health import HealthPlan
from omnican.plan.node import NodeLayout
from omnican.plan.pdo import NodePlan
from omnican.protocol import cia402, heartbeat
from omnican.protocol.cia301 import NmtCommand, NmtState

logger = logging.getLogger("omnican.drive")

_EMCY_KEPT = 32  # EMCYs canopen keeps per node (its log and active list), newest last
LOCKSTEP_SDO_WAIT_S = 0.001  # lock-step: an answer is in the queue when its request was sent


class DriveNode:
    """One node of the base, with the wheels (axes) it drives, on a live network."""

    cyclic_frames: Callable[[Sequence[float]], list[tuple[can.Message, int]]]
    controlword_frame: Callable[[StageDriver], tuple[can.Message, int] | None]

    def __init__(self, network: canopen.Network, layout: NodeLayout,
                 epoch_source: EpochSource, clock: Clock = REAL_TIME) -> None:
        self.layout = layout
        self.clock = clock
        self.node_id = node_id = layout.node_id
        self.settings = settings = layout.settings
        self.network = network
        self.dictionary = layout.dictionary
        self.eds_name = layout.eds.name
        self.mode = layout.mode
        self.has_consumer = layout.has_consumer
        self.plan = layout.plan
        # Initiate answers matched to their request, a late one told from none (sdo_client).
        self.remote: canopen.RemoteNode = CheckedRemoteNode(node_id, self.dictionary, clock,
                                                            settings.sdo_timeout_s)
        # canopen's MAX_RETRIES counts attempts, not retries. In lock-step an answer arrives
        # inside its request's send, or (at opening) on the simulated clock.
        self.remote.sdo.RESPONSE_TIMEOUT = (LOCKSTEP_SDO_WAIT_S if clock.lockstep
                                            else settings.sdo_timeout_s)
        self.remote.sdo.MAX_RETRIES = settings.sdo_retries + 1
        network.add_node(self.remote)
        self.stages = [StageDriver(node_id, s.controlword, s.statusword, s.mode, s.mode_display,
                                   s.error_code, settings.enable_timeout_s)
                       for s in layout.stages]
        self.axes = [AxisIO(a.wheel_index, a.wheel, a.objs, a.target, a.position,
                            self.stages[a.stage]) for a in layout.axes]
        self.io = CyclicIO(network, self.remote, node_id, self.axes, self.stages, epoch_source,
                           settings, clock)
        self.health = NodeHealth(network, node_id, layout.health, clock, settings.sdo_timeout_s)
        if layout.health.sdo:
            self.io.answer_hook = self.health.on_answer
        # The loop's two calls, bound once: no call of ours between it and the frames.
        self.cyclic_frames = self.io.cyclic_frames
        self.controlword_frame = self.io.controlword_frame
        self.sdo_counts: SdoCounts = self.io.build(self.plan)
        sdo = SdoTransfers(self)
        self._sdo_config = SdoConfig(self, sdo)
        #: the PDOs: the plan, or the drive's own mapping (it keeps why it refused the plan)
        self._pdo_config = PdoConfig(self, sdo, self._reset_communication)
        # Liveness and events: written as frames are received (by the loop's poll while
        # the base runs, by python-can's Notifier before and after), read by the loop. The
        # heartbeat is watched from when the configuration switches the drive's producer on.
        self.heartbeat = heartbeat.HeartbeatWatch(heartbeat.timeout_s(
            settings.heartbeat_ms / 1000.0, settings.heartbeat_timeout_factor))
        self.nmt_state: int | None = None
        # Heard OPERATIONAL since its configuration: a node that then reports another
        # state left OPERATIONAL (another master, its own doing); one that never did may
        # only have missed its start.
        self.seen_operational = False
        self.twins = False  # two devices answer as this node: never configured, never talked to
        # Boot-ups seen (only the receiving thread writes it) and the one the present
        # configuration followed (only the configuring thread writes it): a drive that
        # booted since it was configured has lost its configuration.
        self.boot_count = 0
        self.configured_boot = 0
        self._boot_seen = threading.Condition()
        self.emcy: EmcyError | None = None
        self._emcy_log = Throttle(logger, clock=clock.now)
        self.fault_text: str | None = None
        # canopen's NMT master of the node hears its heartbeats (on the receiving thread).
        self.remote.nmt.add_heartbeat_callback(self._on_nmt_state)
        self.remote.emcy.add_callback(self._on_emcy)

    def configure(self, warn: list[str] | None = None) -> None:
        """NMT reset communication and the boot-up (asked again when lost), the PDO plan
        of :mod:`omnican.plan.pdo` (or, for a drive that refuses it, its own mapping,
        restored by another reset communication; objects that mapping lacks go by
        expedited SDO every cycle), the rest by SDO in PRE-OPERATIONAL (mode, ramps,
        heartbeat producer and consumer, 6007h), then NMT start. Blocking, bounded (on the
        opening thread or a re-configuration worker).

        Raises DriveError naming the node and what it was doing; also when two devices
        answer as this node (each boot-up and SDO answer comes twice), before it starts."""
        with nmt.counting_sdo_answers(self):
            self.seen_operational = False
            self._reset_communication()
            # PDOs first: a drive that refuses the plan is reset once more to get its own
            # mapping back, which also resets what the SDO configuration sets in
            # 1000h-1FFFh (1016h, 1017h).
            self._pdo_config.configure(warn)
            self._sdo_config.configure(warn)
            for ax in self.axes:
                ax.reseed()
                ax.raw, ax.epoch = None, -1
            self._pdo_config.drop_canopen_handlers()
        # What failed on the way, said once the answers were all one device's (a second
        # device on this id garbles SDO replies: then its error is the only one).
        for text in self._sdo_config.later:
            logger.warning("%s", text)
        nmt.send(self, NmtCommand.START)

    def _reset_communication(self) -> None:
        """NMT reset communication and the boot-up (:func:`.nmt.reset_communication`)."""

        def cleared() -> None:
            self._sdo_config.watching = False  # a reset communication clears 1016h
            self.heartbeat.producer_off()  # and puts 1017h back to its power-on value

        nmt.reset_communication(self, cleared)

    def use_plan(self, plan: NodePlan) -> None:
        """The PDO plan the drive took (the planned one, or its own mapping)."""
        self.plan = plan
        self.sdo_counts = self.io.build(plan)

    def use_health(self, plan: HealthPlan) -> None:
        """How the drive's health is read from now on (its health TPDOs, or SDO)."""
        self.health.use(plan)
        self.io.answer_hook = self.health.on_answer if plan.sdo else None
        self.io.route_sdo_answers(bool(plan.sdo) or bool(self.plan.sdo))

    def stop(self) -> None:
        """Disable any power stage not known to be off, stop watching the host (consumer
        off) and leave OPERATIONAL; best effort."""
        if not self.boot_count or self.twins:
            return  # never heard, or two devices answering as one: nothing was enabled
        self._sdo_config.stop()
        nmt.enter_pre_operational(self)

    # ------------------------------------------------------------ events

    def _on_nmt_state(self, state: int) -> None:
        """A heartbeat's NMT state (toggle bit masked; 0 a boot-up), from canopen's NMT
        master of the node."""
        self.heartbeat.heard(self.clock.now())
        self.nmt_state = state
        if state == NmtState.OPERATIONAL:
            self.seen_operational = True
        if state == 0:
            with self._boot_seen:
                self.boot_count += 1
                self._boot_seen.notify_all()

    @property
    def rebooted(self) -> bool:
        """The drive booted since its configuration (so it lost that configuration)."""
        return self.boot_count != self.configured_boot

    def _on_emcy(self, error: EmcyError) -> None:
        emcy = self.remote.emcy  # canopen keeps every EMCY: a storm would fill the memory
        with emcy.emcy_received:
            for kept in (emcy.log, emcy.active):
                if len(kept) > _EMCY_KEPT:
                    del kept[:-_EMCY_KEPT]
        if error.code == 0:
            self.fault_text = None
        else:
            self.emcy = error
            self.fault_text = cia402.describe_emcy(error.code)
            # A drive in an EMCY storm (or a device imitating one) gets a line every few
            # seconds per code, with a count, not one per frame.
            self._emcy_log.warning(error.code, "node %d EMCY %s", self.node_id, self.fault_text)

    def heartbeat_lost(self, now: float) -> bool:
        return self.heartbeat.lost(now)


    def detach(self) -> None:
        self._emcy_log.flush()
        self.health.detach()
        self.io.detach()
        if self.node_id in self.network.nodes:
            del self.network[self.node_id]  # canopen's subscriptions go with it (NMT too)
