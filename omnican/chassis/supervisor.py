"""The one owner of every node's lifecycle: configured at startup, watched every few
cycles (faults, heartbeats, reboots, NMT state, another master, per-cycle SDO refusals),
configured again after a reboot or when the bus comes back, recovered, and disabled on
the way out.

Read top to bottom: :meth:`NodeSupervisor.configure_all` (startup), :meth:`check` (each
check, on the loop thread), :meth:`bus_went_down` / :meth:`bus_came_back`,
:meth:`begin_recover` / :meth:`end_recover`, :meth:`disable_all` and :meth:`stop_nodes`
(shutdown). Everything but startup and the re-configuration workers runs on the loop
thread; the workers hand their results back through ``call_soon``. Configuring the nodes
(at startup, and again on worker threads) is :mod:`omnican.chassis.configurator`.

A latched stop (:attr:`latched`, its reason) holds every target at zero until
:meth:`begin_recover` clears it.
"""

from __future__ import annotations

import collections
import logging
import math
from collections.abc import Callable

from omnican.chassis.checks import ChassisChecks
from omnican.chassis.configurator import (
    RECONFIGURE_ATTEMPTS,
    STARTUP_ATTEMPTS,
    Configurator,
    combine_node_errors,
)
from omnican.clock import Clock
from omnican.drive import DriveNode
from omnican.io.bus import CanBus
from omnican.log_throttle import Throttle
from omnican.protocol import cia402
from omnican.protocol.cia301 import (
    NMT_COB_ID,
    NMT_COMMAND_NAMES,
    NmtCommand,
    NmtState,
    nmt_state_name,
)
from omnican.protocol.cia402 import ENABLED_BITS as _ENABLED_BITS
from omnican.protocol.cia402 import ENABLED_MASK as _ENABLED_MASK
from omnican.protocol.cia402 import Command, State, describe_emcy
from omnican.protocol.sdo_cycle import SDO_REQUEST_BASE, download_request

__all__ = ["NMT_RESTART_S", "RECONFIGURE_ATTEMPTS", "STARTUP_ATTEMPTS", "NodeSupervisor",
           "combine_node_errors", "logger"]

logger = logging.getLogger("omnican.chassis")

NMT_RESTART_S = 0.5  # a started node not yet heard OPERATIONAL is started again this often
# Enum members as plain names: each State.X costs a descriptor call on Python 3.11.
_ENABLED, _FAULT, _FAULT_REACTION, _UNKNOWN = (State.OPERATION_ENABLED, State.FAULT,
                                               State.FAULT_REACTION_ACTIVE, State.UNKNOWN)
_PRE_OPERATIONAL, _OPERATIONAL = NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL
_OFF = (State.SWITCH_ON_DISABLED, State.FAULT, State.UNKNOWN)
_NMT_LOG = Throttle(logger)
#: Stops that are the cause of others (which they replace), never replaced themselves.
_CAUSES = ("CAN bus down", "CAN bus-off", "e-stop")


class NodeSupervisor:
    """Every node of one base, from configuration to shutdown (see the module docstring).

    ``call_soon(fn)`` runs ``fn`` on the loop thread at its next cycle."""

    def __init__(self, nodes: list[DriveNode], bus: CanBus, clock: Clock,
                 call_soon: Callable[[Callable[[], None]], None],
                 checks: ChassisChecks) -> None:
        self.nodes = nodes
        #: the drives' health, the wheels' tracking, e-stop, battery, CAN controller
        self.checks = checks
        self._bus = bus
        self.clock = clock
        self.stages = [s for n in nodes for s in n.stages]
        self.latched: str | None = None  # why the base is held stopped
        self.recovering = False  # recover() under way: a silent node may come back
        self.configuring: set[int] = set()  # nodes being configured again (workers)
        self.offline: set[int] = set()  # nodes whose heartbeat was lost
        self.closed = False  # the base is closing: nothing is started again
        self.warnings: list[str] = []  # for the user, from the configuration
        self._nmt_started: dict[int, float] = {}  # when NMT start was last sent, by node
        self._sdo_stop_sent: dict[int, float] = {}  # a quick stop by SDO, by node
        self._sdo_aborts: dict[int, int] = {}  # per-cycle SDO aborts seen, by node
        #: configures the nodes: at startup, and again on worker threads
        self._configurator = Configurator(self, nodes, clock.lockstep, call_soon)
        # NMT commands heard on the bus (receive thread appends, loop pops): never ours,
        # since a bus does not hand a sender its own frames. Another master's.
        self._foreign_nmt: collections.deque[tuple[int, int]] = collections.deque(maxlen=64)
        self._node_ids = frozenset(n.node_id for n in nodes)
        bus.network.subscribe(NMT_COB_ID, self._on_nmt)

    # ------------------------------------------------------------ startup

    def configure_all(self) -> None:
        """Configure every node (in parallel in real time, in order in lock-step) and
        let their stages walk to OPERATION ENABLED, resetting faults on the way. A node
        that reboots while being configured is configured again."""
        self.warnings = self._configurator.configure_all()
        for stage in self.stages:
            stage.set_goal(State.OPERATION_ENABLED, allow_fault_reset=True)

    def started(self) -> None:
        """Every drive is enabled: from now on a fault latches instead of being reset."""
        for stage in self.stages:
            stage.set_goal(State.OPERATION_ENABLED, allow_fault_reset=False)

    def not_enabled_why(self, timeout_s: float) -> str:
        """What kept the base from running within ``timeout_s``, for an error message: the
        stop that holds it (whose cause may be gone since, the drives enabled), else what
        each drive not enabled is doing."""
        enabled = all(s.state is _ENABLED for s in self.stages)
        latched = self.latched
        if latched is not None:
            notes = [f"node {nid} heard again since" for nid in sorted(self._node_ids)
                     if f"node {nid} heartbeat lost" in latched and nid not in self.offline]
            if enabled:
                notes.append("every drive reached OPERATION ENABLED")
            return f"base stopped: {latched}" + (f" ({'; '.join(notes)})" if notes else "")
        problems = [f"node {nid} heartbeat lost" for nid in sorted(self.offline)]
        problems += [s.error for s in self.stages if s.error]
        states = ", ".join(f"node {s.node_id}: {s.state}" for s in self.stages
                           if s.state is not State.OPERATION_ENABLED)
        why = "; ".join(problems) or states or "not every drive seen enabled"
        return f"drives not enabled within {timeout_s:.2g} s ({why})"

    # ------------------------------------------------------------ health (loop thread)

    def latch(self, reason: str) -> None:
        """Hold the base stopped, for ``reason``, until recover(); the first reason stays."""
        if self.latched is None:
            self.latched = reason
            logger.warning("base stopped: %s", reason)

    def latch_cause(self, reason: str) -> None:
        """A stop whose consequences may have latched first (an e-stop takes the drives'
        torque away, bus-off silences them): ``reason`` replaces theirs, not another
        cause's (the bus down, bus-off, an e-stop)."""
        if self.latched is not None and not self.latched.startswith(_CAUSES):
            logger.warning("base stopped: %s", reason)
            self.latched = reason
        self.latch(reason)

    def latch_also(self, reason: str) -> None:
        """Something more found while the base is held stopped (a wheel that turns): said
        after the first reason, which stays first."""
        if self.latched is None:
            self.latch(reason)
            return
        logger.warning("base stopped, and: %s", reason)
        self.latched = f"{self.latched}; {reason}"

    def check(self, now: float, all_enabled: bool = False) -> None:
        """One check of every node not being configured; ``all_enabled``: every
        stage was just seen OPERATION ENABLED (the loop tests that each cycle), so no
        state machine needs a look."""
        configuring, offline, sdo_aborts = self.configuring, self.offline, self._sdo_aborts
        if self._foreign_nmt:
            self._foreign_nmt_seen()
        checks = self.checks
        if now >= checks.next_at:
            checks.check(now, self)
        for node in self.nodes:
            nid = node.node_id
            if nid in configuring:
                continue
            if node.boot_count != node.configured_boot:  # node.rebooted
                self.latch(f"node {nid} rebooted")
                self.reconfigure(node, "its reboot")
                continue
            nmt = node.nmt_state
            if nmt is not None and nmt != _OPERATIONAL and not self.closed:
                if node.seen_operational:
                    self._left_operational(node, nmt, now)
                elif now - self._nmt_started.get(nid, -math.inf) >= NMT_RESTART_S:
                    # Configured and started, yet its heartbeat has never said OPERATIONAL:
                    # the start was lost. Start it.
                    self._start_node(node, now)
            aborts = node.sdo_counts.aborts
            if aborts != sdo_aborts.get(nid, 0):
                # A drive that refuses the target written by SDO each cycle keeps turning
                # at the last one it took: stop the base.
                sdo_aborts[nid] = aborts
                if aborts:
                    self.latch(f"node {nid} refuses its per-cycle SDO transfers "
                               f"({node.sdo_counts.last_abort})")
            watch = node.heartbeat  # watch.lost(now), written out
            since = watch.since
            if since is not None and now - since > watch.timeout_s:
                offline.add(nid)
                if not self.recovering:  # recover() waits for it, and says if it never came
                    self.latch(f"node {nid} heartbeat lost")
            elif nid in offline:  # its heartbeat is back: online again (a stop stays)
                offline.discard(nid)
            if all_enabled:
                continue
            for stage in node.stages:
                sw = stage.statusword_value
                if (sw is not None and sw & _ENABLED_MASK == _ENABLED_BITS) or \
                        stage.allow_fault_reset:
                    continue  # all is well, or the stage driver resets faults (starting up)
                latched = self.latched is not None and not self.recovering
                state = stage.state
                if latched and stage.goal is _ENABLED and state is not _UNKNOWN:
                    # Stopped and out of OPERATION ENABLED (a quick stop, a fault): left
                    # de-energised until recover(), not walked back up meanwhile.
                    stage.set_goal(State.SWITCH_ON_DISABLED)
                if state is _FAULT or state is _FAULT_REACTION:
                    text = node.fault_text or (describe_emcy(stage.error_value)
                                               if stage.error_value else "no EMCY")
                    self.latch(f"node {nid} fault: {text}")
                elif stage.goal is _ENABLED and state is not _UNKNOWN:
                    self.latch(f"node {nid} left OPERATION ENABLED (now {state})")

    def _left_operational(self, node: DriveNode, nmt: int, now: float) -> None:
        """It ran and left OPERATIONAL (another master, the drive itself): it ignores
        every PDO now, the zero targets of a stop included, and sends none (its statuswords
        are no longer news). Nothing moves again without recover(); a drive in
        PRE-OPERATIONAL still takes SDO, so it is told to quick-stop that way."""
        nid = node.node_id
        self.latch(f"node {nid} left OPERATIONAL (now {nmt_state_name(nmt)})")
        for stage in node.stages:
            stage.statusword_value = None
        if nmt == _PRE_OPERATIONAL and now - self._sdo_stop_sent.get(nid, -math.inf) >= \
                NMT_RESTART_S:
            self._sdo_stop_sent[nid] = now
            for stage in node.stages:
                cw = stage.controlword
                quick_stop = cia402.apply_command(stage.cw, Command.QUICK_STOP)
                self._bus.send(SDO_REQUEST_BASE + nid,
                               download_request(cw.index, cw.subindex, cw.encode(quick_stop)))

    def _start_node(self, node: DriveNode, now: float) -> None:
        self._nmt_started[node.node_id] = now
        logger.info("node %d reports %s: starting it", node.node_id,
                    nmt_state_name(node.nmt_state or 0))
        self._bus.send(NMT_COB_ID, bytes([NmtCommand.START, node.node_id]))

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """An NMT command on the bus (receive thread): another master's."""
        if len(data) >= 2 and (data[1] == 0 or data[1] in self._node_ids):
            self._foreign_nmt.append((data[0], data[1]))

    def _foreign_nmt_seen(self) -> None:
        while self._foreign_nmt:
            command, target = self._foreign_nmt.popleft()
            name = NMT_COMMAND_NAMES.get(command, f"0x{command:02X}")
            whom = "all nodes" if target == 0 else f"node {target}"
            if command == NmtCommand.START:  # changes nothing for a node that runs
                _NMT_LOG.warning(("start", target), "another master sent NMT %s to %s",
                                 name, whom)
                continue
            self.latch(f"another master sent NMT {name} to {whom}")

    # ------------------------------------------------------------ configured again

    def reconfigure(self, node: DriveNode, why: str) -> None:
        """Configure ``node`` again on a worker thread (the loop goes on meanwhile, and
        leaves that node's state machine alone until it is done)."""
        self._configurator.reconfigure(node, why)

    def bus_went_down(self, failing: str) -> None:
        """The cause of the lost heartbeats & co. that follow: it replaces their latch."""
        reason = f"CAN bus down ({failing})"
        if self.latched is not None and not self.latched.startswith(_CAUSES):
            logger.warning("base stopped: %s", reason)
            self.latched = reason
        self.latch(reason)

    def bus_came_back(self) -> None:
        """The drives stopped (or rebooted) meanwhile: every one is configured anew, and
        recover() starts them."""
        logger.warning("CAN bus back up; configuring every drive again")
        for node in self.nodes:
            if node.node_id not in self.configuring:
                self.reconfigure(node, "the bus came back")

    # ------------------------------------------------------------ recover (loop thread)

    def begin_recover(self, now: float) -> None:
        """Clear the latch: failed configurations get another go, stopped nodes are
        started, faults are reset on the way to OPERATION ENABLED."""
        self.recovering = True  # a silent node may come back meanwhile
        for node in self.nodes:  # a failed configuration gets another go
            if node.node_id in self._configurator.failed and node.node_id not in self.configuring:
                self.reconfigure(node, "recover()")
        for node in self.nodes:
            if node.node_id in self.offline and not node.heartbeat_lost(now):
                self.offline.discard(node.node_id)
            if (node.node_id not in self.configuring and node.nmt_state is not None
                    and node.nmt_state != _OPERATIONAL):
                node.seen_operational = False  # left OPERATIONAL: start it again
                self._start_node(node, now)
        for stage in self.stages:
            stage.set_goal(State.OPERATION_ENABLED, allow_fault_reset=True)
        self.checks.recovered()
        self.latched = None

    def end_recover(self) -> None:
        """Faults latch again; a node still silent latches its lost heartbeat."""
        self.recovering = False
        for stage in self.stages:
            stage.set_goal(stage.goal, allow_fault_reset=False)
        for nid in sorted(self.offline):
            self.latch(f"node {nid} heartbeat lost")

    # ------------------------------------------------------------ shutdown

    def disable_all(self) -> None:
        """Every stage towards SWITCH ON DISABLED (loop thread)."""
        for stage in self.stages:
            stage.set_goal(State.SWITCH_ON_DISABLED)

    def all_disabled(self) -> bool:
        return all(s.state in _OFF for s in self.stages)

    def join_workers(self, timeout_s: float) -> None:
        self._configurator.join_workers(timeout_s)

    def stop_nodes(self, bus_works: bool) -> None:
        """Each reachable node: disabled by SDO where the loop could not, consumer off,
        PRE-OPERATIONAL (the loop has stopped)."""
        for node in self.nodes:
            if node.node_id not in self.offline and bus_works:
                node.stop()

    def still_powered(self, bus_works: bool = True) -> list[str]:
        """Drives not confirmed disabled, for the closing line: each with what is known
        of it. A drive that is gone (its heartbeat lost: OFFLINE, as the dashboard and
        ``drive --json`` call it; or beyond a bus that is down) is not said to be in the
        state last seen: it is said to be gone, and that state is said as the last seen."""
        out = []
        for st in self.stages:
            if st.state not in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE):
                continue
            if st.node_id in self.offline:
                why = "heartbeat lost" if bus_works else "the CAN bus is down"
                out.append(f"node {st.node_id} (OFFLINE: {why}; last seen {st.state})")
            elif not bus_works:
                out.append(f"node {st.node_id} (unreachable: the CAN bus is down; last seen "
                           f"{st.state})")
            else:
                out.append(f"node {st.node_id} ({st.state})")
        return out

    def detach(self) -> None:
        self._bus.network.unsubscribe(NMT_COB_ID, self._on_nmt)
        for node in self.nodes:
            node.detach()
