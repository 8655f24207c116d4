"""PDO configuration: a node's PDOs, configured through canopen's PdoMap: the plan of
:mod:`omnican.plan.pdo` and the health plan's TPDOs; for a drive that refuses remapping,
its own mapping, read and enabled (what that mapping lacks goes by expedited SDO every
cycle); a health TPDO the drive refuses is read by SDO instead.

Run by :meth:`omnican.drive.node.DriveNode.configure` first thing after the boot-up.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING

import canopen

from omnican.drive.sdo_config import SdoTransfers
from omnican.errors import DriveError
from omnican.plan.health import HealthPlan
from omnican.plan.pdo import NodePlan, PlannedPdo, SdoTransfer
from omnican.protocol.cia301 import COB_ID_INVALID, COB_ID_MASK, TPDO_COMM, TRANS_EVENT, TRANS_SYNC
from omnican.protocol.object_map import Entry, Obj, entry_at

if TYPE_CHECKING:
    from omnican.drive.configurable import ConfigurableNode

logger = logging.getLogger("omnican.drive")


class PdoConfig:
    """The PDO side of one node's configuration. A drive that refused the plan once
    (:attr:`refusal`) keeps its own mapping from then on, after a reboot too."""

    def __init__(self, node: ConfigurableNode, sdo: SdoTransfers,
                 reset: Callable[[], None]) -> None:
        self.node = node
        self._sdo = sdo
        self._reset = reset  # NMT reset communication, and the boot-up: the drive's own mapping
        self.refusal: str | None = None  # why the drive refused the plan (then: its own)

    def configure(self, warn: list[str] | None) -> None:
        """The plan; else (the drive refuses it) the drive's own mapping; what neither
        carries goes by expedited SDO every cycle."""
        node = self.node
        planned = node.layout.plan
        if planned.tried and self.refusal is None:
            names = ", ".join(f"{e.name} ({e.address})" for e in planned.tried)
            _tell(warn, f"node {node.node_id} ({node.eds_name}): its EDS marks {names} not "
                  "PDO-mappable; mapping anyway (chassis.pdo_mapping = \"try\")")
        plan = planned
        if self.refusal is None:
            try:
                self._save_plan(planned)
            except DriveError as exc:
                if "refused" not in str(exc):
                    raise
                self.refusal = str(exc)
                logger.info("node %d refuses the PDO plan (%s); using its own mapping",
                            node.node_id, exc)
                self._reset()  # undoes what was written: its own mapping again
        if self.refusal is not None:  # also after a reboot: not worth another refusal
            plan = self._adopt_existing_mapping(self.refusal)
            why = self.refusal.rpartition("refused: ")[2]
            _tell(warn, f"node {node.node_id} refuses remapping ({why}); using its own PDO mapping")
        if plan.sdo:
            names = ", ".join(f"{t.entry.name} ({t.entry.address})" for t in plan.sdo)
            _tell(warn, f"node {node.node_id}: {names} by expedited SDO every cycle "
                  f"(+{plan.sdo_bits()} bits per cycle)")
        node.use_plan(plan)
        health = node.layout.health
        node.use_health(health.without_pdos() if self.refusal is not None else
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
        self._sdo.write(m.com_record.od.index, 1, (cob | COB_ID_INVALID).to_bytes(4, "little"),
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
        with self._sdo.errors(f"configuring PDO 0x{m.com_record.od.index:04X}"):
            m.save()

    def _adopt_existing_mapping(self, reason: str) -> NodePlan:
        """Find the objects we need in the drive's fixed mapping; enable those PDOs."""
        node = self.node
        with self._sdo.errors("reading its PDO mapping"):
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
        controlwords = [s.controlword for s in node.stages]
        rx_wanted = targets + controlwords
        # The controlwords every cycle too (chassis.cyclic_controlword): their PDOs on SYNC.
        every_cycle = targets + controlwords if node.settings.cyclic_controlword else targets
        tx_wanted = [a.position for a in node.axes] + [s.statusword for s in node.stages]
        rpdos: list[PlannedPdo] = []
        tpdos: list[PlannedPdo] = []
        sdo: list[SdoTransfer] = []
        for maps, wanted, out, tx in ((node.remote.rpdo, rx_wanted, rpdos, False),
                                      (node.remote.tpdo, tx_wanted, tpdos, True)):
            chosen, missing = pick(maps, wanted)
            # Last resort: targets and controlwords written, positions and statuswords
            # read, by SDO (every cycle; controlwords as they go by PDO).
            sdo += [SdoTransfer(e, write=not tx, cyclic=tx or e in every_cycle) for e in missing]
            for number, _present in chosen:
                m = maps[number]
                entries = []
                for v in m:
                    entry = self._entry_for(v.index, v.subindex)
                    entries.append(entry)
                cyclic = tx and any(e in [a.position for a in node.axes] for e in entries)
                cyclic = cyclic or (not tx and any(e in every_cycle for e in entries))
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
        self._sdo.write(index, 1, (cob | COB_ID_INVALID).to_bytes(4, "little"), "PDO COB-ID")
        if m.com_record.od[2].writable:
            self._sdo.write(index, 2, bytes([trans]), "PDO transmission type")
        if index >= TPDO_COMM and trans == TRANS_EVENT and 3 in m.com_record.od.subindices:
            self._sdo.write(index, 3, (20).to_bytes(2, "little"), "PDO inhibit time")
        self._sdo.write(index, 1, cob.to_bytes(4, "little"), "PDO COB-ID")

    def drop_canopen_handlers(self) -> None:
        """canopen's PdoMap subscribes its own decoder to each PDO it saves or reads;
        omnican decodes the frames itself, so that work (every frame, every cycle) goes."""
        node = self.node
        for maps in (node.remote.rpdo, node.remote.tpdo):
            for m in (maps.map or {}).values():
                cob = m.cob_id
                if cob is not None and m.on_message in node.network.subscribers.get(cob, []):
                    node.network.unsubscribe(cob, m.on_message)


def _tell(warn: list[str] | None, text: str) -> None:
    """A warning for the user: into ``warn`` at startup (the chassis shows them), else the log."""
    if warn is not None:
        warn.append(text)
    else:
        logger.warning("%s", text)
