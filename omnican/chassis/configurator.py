"""Configuring the nodes of a base: every one at startup (in parallel in real time, in
order in lock-step; a node that reboots meanwhile is configured again), and one again on
a worker thread after a reboot, when the bus comes back, or at recover() after a failed
attempt. The workers hand their results back to the loop thread through ``call_soon``.

:class:`omnican.chassis.supervisor.NodeSupervisor` owns one :class:`Configurator`, and
is what it reports to (:class:`Supervised`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Protocol

from omnican.drive import DriveNode
from omnican.errors import DriveError, OmnicanError
from omnican.protocol.cia402 import State

logger = logging.getLogger("omnican.chassis")  # the supervisor's: one story in the log

RECONFIGURE_ATTEMPTS = 2  # a node configured again (reboot, bus back) that fails once
STARTUP_ATTEMPTS = 3  # configurations of a node that reboots while being configured


class Supervised(Protocol):
    """What the configurator reads and tells of the supervisor that owns it
    (:class:`omnican.chassis.supervisor.NodeSupervisor`; read on the loop thread, and
    ``closed`` by the workers)."""

    closed: bool  # the base is closing: no attempt again
    recovering: bool  # recover() under way: a node configured again is enabled
    configuring: set[int]  # nodes being configured again (workers)

    def latch(self, reason: str) -> None: ...


class Configurator:
    """Configures the nodes of ``sup`` (see the module docstring). ``call_soon(fn)`` runs
    ``fn`` on the loop thread at its next cycle."""

    def __init__(self, sup: Supervised, nodes: list[DriveNode], lockstep: bool,
                 call_soon: Callable[[Callable[[], None]], None]) -> None:
        self._sup = sup
        self._nodes = nodes
        self._lockstep = lockstep
        self._call_soon = call_soon
        self.failed: set[int] = set()  # nodes whose re-configuration failed
        self._workers: list[threading.Thread] = []

    def configure_all(self) -> list[str]:
        """Configure every node (in parallel in real time, in order in lock-step); a node
        that reboots while being configured is configured again. Returns the warnings
        for the user (also logged)."""
        warnings: list[str] = []
        pending = list(self._nodes)
        for _attempt in range(STARTUP_ATTEMPTS):
            self._configure(pending, warnings)
            # A drive that booted again while it was being configured lost part of it.
            pending = [n for n in self._nodes if n.rebooted]
            if not pending:
                break
            logger.info("nodes %s rebooted during their configuration; configuring again",
                        [n.node_id for n in pending])
        else:
            raise DriveError(f"nodes {[n.node_id for n in pending]} keep rebooting while "
                             "being configured (power supply? a watchdog of their own?)")
        for node in self._nodes:
            _seed_statuswords(node)
        for w in warnings:
            logger.warning("%s", w)
        return warnings

    def _configure(self, nodes: list[DriveNode], warnings: list[str]) -> None:
        errors: list[str] = []

        def note(node: DriveNode, exc: Exception) -> None:
            errors.append(str(exc) if isinstance(exc, OmnicanError) else
                          f"node {node.node_id}: {exc}")

        if self._lockstep:  # one thread, in order: deterministic
            for node in nodes:
                try:
                    node.configure(warnings)
                except Exception as exc:
                    note(node, exc)
        else:
            with ThreadPoolExecutor(len(nodes), thread_name_prefix="omnican-cfg") as ex:
                futures = {ex.submit(n.configure, warnings): n for n in nodes}
                for fut, node in futures.items():
                    try:
                        fut.result()
                    except Exception as exc:
                        note(node, exc)
        if errors:
            raise DriveError(combine_node_errors(errors, len(self._nodes)))

    def reconfigure(self, node: DriveNode, why: str) -> None:
        """Configure ``node`` again on a worker thread (the loop goes on meanwhile, and
        leaves that node's state machine alone until it is done)."""
        call_soon, sup = self._call_soon, self._sup
        sup.configuring.add(node.node_id)
        for stage in node.stages:
            stage.forget()
            stage.set_goal(State.SWITCH_ON_DISABLED)
        for ax in node.axes:
            ax.reseed()

        def work() -> None:
            try:
                for attempt in range(RECONFIGURE_ATTEMPTS):
                    try:
                        node.configure()
                        break
                    except DriveError as exc:  # a drive still booting, an SDO lost
                        if attempt + 1 == RECONFIGURE_ATTEMPTS or sup.closed:
                            raise
                        logger.info("re-configuring node %d: %s; trying again", node.node_id,
                                    exc)
                _seed_statuswords(node)
                logger.info("node %d re-configured after %s", node.node_id, why)
                call_soon(lambda: self._configured(node))
            except Exception as exc:
                logger.error("re-configuring node %d failed: %s", node.node_id, exc)
                call_soon(lambda: self.failed.add(node.node_id))
                # Not again until the drive boots once more (it announces that itself).
                node.configured_boot = node.boot_count
                reason = f"re-configuring node {node.node_id} failed: {exc}"
                call_soon(lambda: sup.latch(reason))
            finally:
                call_soon(lambda: sup.configuring.discard(node.node_id))

        if self._lockstep:  # the simulated drives answer at once: no thread, no waiting
            work()
            return
        t = threading.Thread(target=work, name=f"omnican-reconfigure-{node.node_id}", daemon=True)
        self._workers = [w for w in self._workers if w.is_alive()]
        self._workers.append(t)
        t.start()

    def _configured(self, node: DriveNode) -> None:
        """A re-configuration ended well (loop thread): a recover() waiting for it wants
        the node enabled."""
        self.failed.discard(node.node_id)
        if self._sup.recovering:
            for stage in node.stages:
                stage.set_goal(State.OPERATION_ENABLED, allow_fault_reset=True)

    def join_workers(self, timeout_s: float) -> None:
        for t in self._workers:
            t.join(timeout=timeout_s)


def _seed_statuswords(node: DriveNode) -> None:
    """Read each statusword once by SDO: a drive need not send its event TPDO at start."""
    for stage in node.stages:
        sw = stage.statusword
        try:
            raw = node.remote.sdo.upload(sw.index, sw.subindex)
        except Exception as exc:  # the TPDO will tell; this is only a head start
            logger.debug("node %d: statusword read failed: %s", node.node_id, exc)
            continue
        if stage.statusword_value is None:
            stage.statusword_value = sw.decode(raw) & 0xFFFF


def combine_node_errors(errors: list[str], nodes: int) -> str:
    """``node 1: X; node 2: X`` as ``nodes 1, 2: X``: one reason said once; when no node
    at all sent its boot-up, say there is no drive on the bus."""
    groups: dict[str, list[str]] = {}
    for error in errors:
        head, sep, reason = error.partition(": ")
        if sep and head.startswith("node ") and head[5:].isdigit():
            groups.setdefault(reason, []).append(head[5:])
        else:
            groups.setdefault(error, [])
    parts = []
    for reason, ids in groups.items():
        if len(ids) > 1:
            parts.append(f"nodes {', '.join(ids)}: {reason}")
        else:
            parts.append(f"node {ids[0]}: {reason}" if ids else reason)
    text = "; ".join(parts)
    if len(groups) == 1 and len(errors) == nodes and "no boot-up" in text:
        text = f"no drive answered on the bus: {text}"
    return text
