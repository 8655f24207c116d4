"""NMT and boot (CiA 301, CiA 302-2's boot process): the NMT commands omnican sends a
node (reset communication, start, enter pre-operational), waiting for its boot-up
(asking with an SDO read of 1000h whether a silent node is there), and two devices
answering as one node id (each boot-up and SDO answer comes twice): refused before the
node is started.

What a node's heartbeats say (its NMT state, a boot-up) canopen's NMT master of the
node hears (``RemoteNode.nmt``) and hands to :class:`omnican.drive.node.DriveNode`. The
commands go out here as the two-byte frame they are: canopen's ``NmtMaster.send_command``
raises KeyError once a heartbeat has reported a state outside its table (a shared bus
carries such frames), and its ``wait_for_bootup`` waits on wall time, not on the node's
clock.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

import can
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican.errors import DriveError
from omnican.protocol.cia301 import DEVICE_TYPE, NMT_COB_ID, NmtCommand

if TYPE_CHECKING:
    from omnican.drive.configurable import ConfigurableNode

logger = logging.getLogger("omnican.drive")

BOOT_RESETS = 4  # NMT resets sent (within boot_timeout_s) before a node counts as absent


def send(node: ConfigurableNode, command: NmtCommand) -> None:
    """One NMT command to ``node`` (COB-ID 0: the command, the node id)."""
    node.network.send_message(NMT_COB_ID, bytes([command, node.node_id]))


def enter_pre_operational(node: ConfigurableNode) -> None:
    """The way out's last step, best effort: a bus that refuses the frame (down, its
    transmit queue full) is logged, not raised (the drives' heartbeat consumers stop
    them anyway)."""
    try:
        send(node, NmtCommand.ENTER_PRE_OPERATIONAL)
    except (can.CanError, OSError, RuntimeError) as exc:
        logger.debug("node %d: NMT pre-operational not sent: %s", node.node_id, exc)


def reset_communication(node: ConfigurableNode, on_reset: Callable[[], None]) -> None:
    """NMT reset communication and wait for the boot-up: the drive's 1000h-1FFFh
    (PDOs, heartbeat) are back at their power-on values.

    Every ``boot_timeout_s / BOOT_RESETS`` without a boot-up, one SDO read of 1000h
    asks whether the node is there (CiA 302-2's boot process). A node that answers is
    booting: a new reset would start its boot again, so it gets the whole boot time
    (then one more reset, for a reset or a boot-up lost on the way). A silent one is
    sent the reset again (it may have missed it); it fails after the boot time.
    ``on_reset`` is called as each reset is sent (it clears 1016h, for one)."""
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
        on_reset()
        send(node, NmtCommand.RESET_COMMUNICATION)
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
        alive = answers_device_type(node)
        if booted():
            break
        now = clock.now()
        answered = answered or alive
        if answered:  # there, now or at an earlier ask (an answer may be lost too)
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
        raise DriveError(twins_text(node, f"{count} boot-ups answered one NMT reset"))
    with node._boot_seen:
        node.configured_boot = node.boot_count


def answers_device_type(node: ConfigurableNode) -> bool:
    """One SDO read of the device type (1000h), one attempt: the node is there."""
    sdo = node.remote.sdo
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


def twins_text(node: ConfigurableNode, evidence: str) -> str:
    """What a node two devices answer as is told."""
    return (f"node {node.node_id}: two devices answer as node {node.node_id} ({evidence}): "
            "a cloned drive? give each its own node id")


@contextlib.contextmanager
def counting_sdo_answers(node: ConfigurableNode) -> Iterator[None]:
    """Count this node's SDO answers against the requests sent meanwhile: a second
    device on the same id answers every request too."""
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
            return twins_text(node, f"{answers[0]} SDO answers to {sent} requests")
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

