"""Configuring a node over SDO, and the way out.

:meth:`NodeSetup.configure` (blocking, bounded, on the opening thread or a
re-configuration worker): NMT reset communication and the boot-up (asked again when
lost), the PDO plan of :mod:`omnican.plan.pdo` (or, for a drive that refuses it, its own
mapping, restored by another reset communication; objects that mapping lacks go by
expedited SDO every cycle), mode, ramps, heartbeat producer and consumer, 6007h, then
NMT OPERATIONAL. Two devices answering as one node are refused before the start.
:meth:`NodeSetup.stop` disables what the loop could not, clears the consumer and leaves
OPERATIONAL.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator
from dataclasses import replace
from typing import Any, Protocol

import can
import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican.clock import Clock
from omnican.config import ChassisSettings
from omnican.drive.cyclic import AxisIO
from omnican.drive.health import NodeHealth
from omnican.drive.sdoclient import SdoTooSlowError
from omnican.drive.stage import StageDriver
from omnican.errors import DriveError
from omnican.plan.health import HealthPlan
from omnican.plan.node import NodeLayout
from omnican.plan.pdo import NodePlan, PlannedPdo, SdoTransfer
from omnican.protocol import cia402, heartbeat
from omnican.protocol.cia301 import (
    COB_ID_INVALID,
    COB_ID_MASK,
    CONSUMER_HEARTBEAT_TIME,
    DEVICE_TYPE,
    NMT_COB_ID,
    PRODUCER_HEARTBEAT_TIME,
    TPDO_COMM,
    TRANS_EVENT,
    TRANS_SYNC,
    NmtCommand,
    NmtState,
    abort_text,
)
from omnican.protocol.cia402 import Command, Mode, State
from omnican.protocol.object_map import Entry, Obj, entry_at, obj_name


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

    def use_plan(self, plan: NodePlan) -> None: ...

    def use_health(self, plan: HealthPlan) -> None: ...

logger = logging.getLogger("omnican.drive")

# Power stages with no torque: nothing to disable on the way out.
_OFF_STATES = frozenset({State.SWITCH_ON_DISABLED, State.NOT_READY_TO_SWITCH_ON, State.FAULT})
MODE_READS, MODE_READ_GAP_S = 4, 0.05  # the mode display read back after setting the mode
BOOT_RESETS = 4  # NMT resets sent (within boot_timeout_s) before a node counts as absent


class NodeSetup:
    """The SDO side of one node: its configuration and its way out."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self._refusal: str | None = None  # why the drive refused the plan (then: its own)
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
        with self._counting_sdo_answers():
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
        self._configure_pdos(warn)
        for stage in node.stages:
            stage.forget()
            if stage.mode is not None:
                self._write_value(stage.mode, int(node.mode), f"mode {node.mode.short}")
            self._confirm_mode(stage)
        self._configure_ramps()
        self._read_rated_currents()
        for write in node.layout.settings_writes:  # [[wheel.sdo]]
            self._sdo_write(write.entry, write.entry.subindex, write.data,
                            f"{write.entry.name} from {write.origin}")
        self._sdo_write(PRODUCER_HEARTBEAT_TIME, 0, s.heartbeat_ms.to_bytes(2, "little"),
                        "heartbeat producer")
        if node.has_consumer:
            ms = heartbeat.consumer_time_ms(s.heartbeat_ms, s.heartbeat_timeout_factor)
            value = (s.host_node_id << 16) | ms
            self._watching = True  # also if the write's answer is lost
            self._sdo_write(CONSUMER_HEARTBEAT_TIME, 1, value.to_bytes(4, "little"),
                            "heartbeat consumer")
            abort = node.axes[0].objs.get(Obj.ABORT_OPTION)
            if abort is not None:
                self._write_value(abort, cia402.ABORT_QUICK_STOP, "abort connection option")
        elif warn is not None:
            warn.append(f"node {node.node_id} ({node.eds_name}) has no heartbeat consumer (1016h):"
                        " it will not stop by itself if this host dies")
        for ax in node.axes:
            ax.reseed()
            ax.raw, ax.epoch = None, -1
        self._drop_canopen_pdo_handlers()

    def _drop_canopen_pdo_handlers(self) -> None:
        """canopen's PdoMap subscribes its own decoder to each PDO it saves or reads;
        omnican decodes the frames itself, so that work (every frame, every cycle) goes."""
        node = self.node
        for maps in (node.remote.rpdo, node.remote.tpdo):
            for m in (maps.map or {}).values():
                cob = m.cob_id
                if cob is not None and m.on_message in node.network.subscribers.get(cob, []):
                    node.network.unsubscribe(cob, m.on_message)

    def _reset_communication(self) -> None:
        """NMT reset communication and wait for the boot-up: the drive's 1000h-1FFFh
        (PDOs, heartbeat) are back at their power-on values.

        Every ``boot_timeout_s / BOOT_RESETS`` without a boot-up, one SDO read of 1000h
        asks whether the node is there (CiA 302-2's boot process). A node that answers is
        booting: a new reset would start its boot again, so it gets the whole boot time
        (then one more reset, for a reset or a boot-up lost on the way). A silent one is
        sent the reset again (it may have missed it); it fails after the boot time."""
        node = self.node
        s = node.settings
        clock = node.clock
        waits = not clock.lockstep or clock.can_wait  # lock-step inside a task: no waiting
        interval = s.boot_timeout_s / BOOT_RESETS
        with node._boot_seen:
            before = node.boot_count

        def booted() -> int:
            with node._boot_seen:
                return node.boot_count - before

        def wait_boot(until: float) -> int:
            left = until - clock.now()
            if clock.lockstep:
                if waits and left > 0:
                    clock.run_until(booted, left, 0.001)  # type: ignore[attr-defined]
                return booted()
            with node._boot_seen:
                node._boot_seen.wait_for(lambda: node.boot_count != before, max(left, 0.0))
                return node.boot_count - before

        def reset() -> float:
            self._watching = False  # a reset communication clears 1016h
            node.network.send_message(NMT_COB_ID,
                                      bytes([NmtCommand.RESET_COMMUNICATION, node.node_id]))
            return clock.now()

        last_reset = reset()
        resets, answered, retried_alive = 1, False, False
        end = last_reset + s.boot_timeout_s
        next_check = last_reset + interval
        while not booted():
            if not waits:  # nothing can come meanwhile: the resets at once
                if resets >= BOOT_RESETS:
                    break
                last_reset, resets = reset(), resets + 1
                continue
            if wait_boot(min(next_check, end)):
                break
            if clock.now() >= end and (not answered or retried_alive):
                break
            alive = self._answers_1000h()
            if booted():
                break
            now = clock.now()
            if alive:
                answered = True
                if now >= last_reset + s.boot_timeout_s:
                    if retried_alive:
                        break
                    # There, but no boot-up for a whole boot time: the reset or its
                    # boot-up was lost. Once more, with another boot time to answer.
                    last_reset, resets, retried_alive = reset(), resets + 1, True
                    now = last_reset
                end = max(end, last_reset + s.boot_timeout_s)
            elif now < end:
                last_reset, resets = reset(), resets + 1  # silent: it may have missed it
                now = last_reset
            else:
                break
            next_check = now + interval
        count = booted()
        if not count:
            if answered:
                raise DriveError(f"node {node.node_id}: answers SDOs but sent no boot-up within "
                                 f"{s.boot_timeout_s:g} s of an NMT reset communication (sent "
                                 f"{resets} times; raise chassis.boot_timeout_s?)")
            within = f" within {s.boot_timeout_s:g} s" if waits else ""
            raise DriveError(f"node {node.node_id}: no boot-up{within} after NMT reset "
                             f"communication (sent {resets} times; powered? node id? "
                             "bitrate?)")
        if resets == 1 and count > 1:  # one reset, two boot-ups
            node.twins = True
            raise DriveError(self._twins(f"{count} boot-ups answered one NMT reset"))
        with node._boot_seen:
            node.configured_boot = node.boot_count

    def _answers_1000h(self) -> bool:
        """One SDO read of the device type (1000h), one attempt: the node is there."""
        sdo = self.node.remote.sdo
        retries = sdo.MAX_RETRIES
        sdo.MAX_RETRIES = 1
        try:
            sdo.upload(DEVICE_TYPE, 0)
            return True
        except SdoAbortedError:
            return True  # an abort is an answer too
        except (SdoCommunicationError, can.CanError, OSError):
            return False
        finally:
            sdo.MAX_RETRIES = retries

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
            with self._sdo_errors(f"reading the mode display ({display.address})"):
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

    def _twins(self, evidence: str) -> str:
        node = self.node
        return (f"node {node.node_id}: two devices answer as node {node.node_id} ({evidence}): "
                "a cloned drive? give each its own node id")

    @contextlib.contextmanager
    def _counting_sdo_answers(self) -> Iterator[None]:
        """Count this node's SDO answers against the requests sent meanwhile: a second
        device on the same id answers every request too."""
        node = self.node
        answers = [0]

        def count(can_id: int, data: bytearray, timestamp: float) -> None:
            answers[0] += 1

        requests: dict[int, int] = getattr(node.network, "sdo_requests", {})
        asked = requests.get(node.node_id, 0)
        cob = node.remote.sdo.tx_cobid

        def twins() -> str | None:
            sent = requests.get(node.node_id, 0) - asked
            if sent and answers[0] >= 3 + 1.5 * sent:
                node.twins = True
                return self._twins(f"{answers[0]} SDO answers to {sent} requests")
            return None

        node.network.subscribe(cob, count)
        try:
            yield
        except DriveError:
            found = twins()  # what failed may be the second device's doing
            if found is not None:
                raise DriveError(found) from None
            raise
        finally:
            node.network.unsubscribe(cob, count)
        found = twins()
        if found is not None:
            raise DriveError(found)

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
                        self._sdo_write(index, 1, round(rate * scale).to_bytes(4, "little"),
                                        "vl ramp delta speed")
                        self._sdo_write(index, 2, (1).to_bytes(2, "little"), "vl ramp delta time")
                continue
            for obj, rate in ((Obj.PROFILE_ACCEL, wheel_accel), (Obj.PROFILE_DECEL, wheel_stop),
                              (Obj.QUICK_STOP_DECEL, wheel_stop)):
                entry = ax.objs.get(obj)
                if entry is not None:
                    self._write_value(entry, round(rate * scale), obj_name(obj))

    def _configure_pdos(self, warn: list[str] | None) -> None:
        """The plan; else (the drive refuses it) the drive's own mapping; what neither
        carries goes by expedited SDO every cycle."""
        node = self.node
        planned = node.layout.plan
        if planned.tried and self._refusal is None:
            names = ", ".join(f"{e.name} ({e.address})" for e in planned.tried)
            _tell(warn, f"node {node.node_id} ({node.eds_name}): its EDS marks {names} not "
                  "PDO-mappable; mapping anyway (chassis.pdo_mapping = \"try\")")
        plan = planned
        if self._refusal is None:
            try:
                self._save_plan(planned)
            except DriveError as exc:
                if "refused" not in str(exc):
                    raise
                self._refusal = str(exc)
                logger.info("node %d refuses the PDO plan (%s); using its own mapping",
                            node.node_id, exc)
                self._reset_communication()  # undoes what was written: its own mapping again
        if self._refusal is not None:  # also after a reboot: not worth another refusal
            plan = self._adopt_existing_mapping(self._refusal)
            why = self._refusal.rpartition("refused: ")[2]
            _tell(warn, f"node {node.node_id} refuses remapping ({why}); using its own PDO mapping")
        if plan.sdo:
            names = ", ".join(f"{t.entry.name} ({t.entry.address})" for t in plan.sdo)
            _tell(warn, f"node {node.node_id}: {names} by expedited SDO every cycle "
                  f"(+{plan.sdo_bits()} bits per cycle)")
        node.use_plan(plan)
        health = node.layout.health
        node.use_health(health.without_pdos() if self._refusal is not None else
                        self._save_health_pdos(health))

    def _save_health_pdos(self, plan: HealthPlan) -> HealthPlan:
        """The health TPDOs; one the drive refuses is disabled and its objects are read
        by SDO instead (the rest of the plan stands)."""
        node = self.node
        kept = []
        for p in plan.pdos:
            m = node.remote.tpdo[p.number]
            try:
                self._write_map(m, p)
                kept.append(p)
            except DriveError as exc:
                if "refused" not in str(exc):
                    raise
                logger.info("node %d: health TPDO%d refused (%s); reading it by SDO",
                            node.node_id, p.number, exc)
                self._disable_pdo(m)
        if len(kept) == len(plan.pdos):
            return plan
        dropped = {(e.index, e.subindex) for p in plan.pdos if p not in kept for e in p.entries}
        return replace(plan, pdos=tuple(kept), sdo=plan.sdo + tuple(
            r for r in plan.reads if r.key in dropped and not r.pdo_only))

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
                raise DriveError(self._too_slow(exc)) from None
            except (SdoAbortedError, SdoCommunicationError) as exc:
                self._later.append(f"node {node.node_id}: reading the rated current "
                                   f"({rated.address}) failed: {exc}")
                continue
            node.health.scales[read.key] = rated.decode(raw) / 1_000_000.0  # mA per mille

    def _save_plan(self, plan: NodePlan) -> None:
        node = self.node
        for number in plan.unused_rpdos:
            self._disable_pdo(node.remote.rpdo[number])
        for number in plan.unused_tpdos:
            self._disable_pdo(node.remote.tpdo[number])
        for planned, maps in ((plan.rpdos, node.remote.rpdo), (plan.tpdos, node.remote.tpdo)):
            for p in planned:
                self._write_map(maps[p.number], p)

    def _disable_pdo(self, m: canopen.pdo.PdoMap) -> None:
        cob = (m.predefined_cob_id or (m.com_record.od[1].default or 0)) & COB_ID_MASK
        self._sdo_write(m.com_record.od.index, 1, (cob | COB_ID_INVALID).to_bytes(4, "little"),
                        "PDO COB-ID (disable)")

    def _write_map(self, m: canopen.pdo.PdoMap, p: PlannedPdo) -> None:
        """One planned PDO (the cyclic plan's or the health plan's) into the drive: its mapping
        and communication parameters, through canopen's PdoMap."""
        m.clear()
        for entry in p.entries:
            m.add_variable(entry.index, entry.subindex, entry.bits)
        m.cob_id, m.trans_type, m.enabled = p.cob_id, p.trans_type, True
        m.inhibit_time, m.event_timer = p.inhibit_100us, p.event_timer_ms
        self._save_map(m)

    def _save_map(self, m: canopen.pdo.PdoMap) -> None:
        with self._sdo_errors(f"configuring PDO 0x{m.com_record.od.index:04X}"):
            m.save()

    def _adopt_existing_mapping(self, reason: str) -> NodePlan:
        """Find the objects we need in the drive's fixed mapping; enable those PDOs."""
        node = self.node
        with self._sdo_errors("reading its PDO mapping"):
            node.remote.rpdo.read()
            node.remote.tpdo.read()

        def keys(m: canopen.pdo.PdoMap) -> list[tuple[int, int]]:
            return [(v.index, v.subindex) for v in m]

        def pick(maps: canopen.pdo.PdoBase,
                 wanted: list[Entry]) -> tuple[list[tuple[int, list[Entry]]], list[Entry]]:
            chosen: list[tuple[int, list[Entry]]] = []
            missing = list(wanted)
            for number, m in sorted((maps.map or {}).items()):
                present = [e for e in missing if (e.index, e.subindex) in keys(m)]
                if present:
                    chosen.append((number, present))
                    missing = [e for e in missing if e not in present]
            return chosen, missing

        targets = [a.target for a in node.axes]
        rx_wanted = targets + [s.controlword for s in node.stages]
        tx_wanted = [a.position for a in node.axes] + [s.statusword for s in node.stages]
        rpdos: list[PlannedPdo] = []
        tpdos: list[PlannedPdo] = []
        sdo: list[SdoTransfer] = []
        for maps, wanted, out, tx in ((node.remote.rpdo, rx_wanted, rpdos, False),
                                      (node.remote.tpdo, tx_wanted, tpdos, True)):
            chosen, missing = pick(maps, wanted)
            # Last resort: targets and controlwords written, positions and statuswords
            # read, by SDO (every cycle; controlwords when they change).
            sdo += [SdoTransfer(e, write=not tx, cyclic=tx or e in targets) for e in missing]
            for number, _present in chosen:
                m = maps[number]
                entries = []
                for v in m:
                    entry = self._entry_for(v.index, v.subindex)
                    entries.append(entry)
                cyclic = tx and any(e in [a.position for a in node.axes] for e in entries)
                cyclic = cyclic or (not tx and any(e in [a.target for a in node.axes]
                                                   for e in entries))
                trans = TRANS_SYNC if cyclic else TRANS_EVENT
                cob = (m.cob_id or m.predefined_cob_id or 0) & COB_ID_MASK
                self._save_comm_only(m, cob, trans)
                out.append(PlannedPdo(number, cob, trans, tuple(entries)))
        logger.debug("node %d: own mapping adopted (%s)", node.node_id, reason)
        return NodePlan(node.node_id, tuple(rpdos), tuple(tpdos),
                        notes=("fixed mapping (drive refuses remapping)",), sdo=tuple(sdo))

    def _entry_for(self, index: int, subindex: int) -> Entry:
        node = self.node
        for ax in node.axes:
            for obj in (Obj.TARGET_VELOCITY, Obj.VL_TARGET, Obj.POSITION_ACTUAL, Obj.CONTROLWORD,
                        Obj.STATUSWORD, Obj.MODE, Obj.MODE_DISPLAY, Obj.ERROR_CODE,
                        Obj.VELOCITY_ACTUAL):
                e = ax.objs.get(obj)
                if e is not None and (e.index, e.subindex) == (index, subindex):
                    return e
        return entry_at(node.dictionary, index, subindex)  # an object we do not own: sent as 0

    def _save_comm_only(self, m: canopen.pdo.PdoMap, cob: int, trans: int) -> None:
        """Enable a PDO with its fixed mapping: COB-ID and transmission type only."""
        index = m.com_record.od.index
        self._sdo_write(index, 1, (cob | COB_ID_INVALID).to_bytes(4, "little"), "PDO COB-ID")
        if m.com_record.od[2].writable:
            self._sdo_write(index, 2, bytes([trans]), "PDO transmission type")
        if index >= TPDO_COMM and trans == TRANS_EVENT and 3 in m.com_record.od.subindices:
            self._sdo_write(index, 3, (20).to_bytes(2, "little"), "PDO inhibit time")
        self._sdo_write(index, 1, cob.to_bytes(4, "little"), "PDO COB-ID")

    # ------------------------------------------------------------ cyclic I/O

    @contextlib.contextmanager
    def _sdo_errors(self, doing: str) -> Iterator[None]:
        """SDO failures as one DriveError naming the node, what it was doing and why."""
        node = self.node
        try:
            yield
        except SdoAbortedError as exc:
            raise DriveError(f"node {node.node_id}: {doing} refused: {abort_text(exc.code)}"
                             ) from None
        except SdoTooSlowError as exc:
            raise DriveError(self._too_slow(exc)) from None
        except SdoCommunicationError:
            sdo = node.remote.sdo
            wait = node.settings.sdo_timeout_s if not node.clock.lockstep else 0.0
            raise DriveError(f"node {node.node_id}: no SDO answer {doing} ({sdo.MAX_RETRIES} "
                             f"attempts{f', {wait:g} s each' if wait else ''})") from None

    def _too_slow(self, exc: SdoTooSlowError) -> str:
        timeout = self.node.settings.sdo_timeout_s
        return (f"node {self.node.node_id} answers SDOs after {exc.late_s:.2f} s, slower than "
                f"chassis.sdo_timeout_s {timeout:g} s: raise it")

    def _sdo_write(self, entry_or_index: Entry | int, subindex: int, data: bytes,
                   what: str) -> None:
        node = self.node
        index = entry_or_index.index if isinstance(entry_or_index, Entry) else entry_or_index
        with self._sdo_errors(f"writing {what} (0x{index:04X}:{subindex:02X})"):
            node.remote.sdo.download(index, subindex, data)

    def _write_value(self, entry: Entry, value: int, what: str) -> None:
        if entry.writable:
            self._sdo_write(entry, entry.subindex, entry.encode(value), what)

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



def _tell(warn: list[str] | None, text: str) -> None:
    """A warning for the user: into ``warn`` at startup (the chassis shows them), else the log."""
    if warn is not None:
        warn.append(text)
    else:
        logger.warning("%s", text)
