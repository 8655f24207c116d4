"""Commissioning: give the drives the node ids the config names for their serials (LSS,
CiA 305), store them, reset them and read them back (the settings they keep:
:mod:`omnican.analysis.parameters`).

Built on python canopen's :class:`canopen.lss.LssMaster` (fast scan, switch state,
configure node id and bit timing, store, inquire): nothing of LSS is written here but
the order of the steps and what is checked between them.

:func:`commission` finds the drives without a node id (FFh) by fast scan, and the drives
that run with another node id than the config gives their serial by their identity
(1018h, read by SDO), gives each its node id, stores it, resets it and checks that it
came back as that node with that serial. What it found and did is a
:class:`Commissioning`: a row per drive, whatever happened, and the problems, one line
each. Another master on the bus (LSS requests or NMT commands this process did not
send) stops it before it changes anything, or before the next drive. Nothing here
prints; ``omnican commission`` does.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any, TypeVar

import canopen
from canopen.lss import LssError

from omnican.analysis.master import (
    BOOT_WAIT_S,
    Identity,
    MasterWatch,
    identities,
)
from omnican.config import ChassisConfig
from omnican.errors import ConfigError
from omnican.io.bus import CanBus
from omnican.protocol.cia301 import (
    NMT_COB_ID,
    NmtCommand,
)

logger = logging.getLogger(__name__)

UNCONFIGURED = 0xFF
#: CiA 305 table 0: bit/s -> bit timing index.
BIT_TIMING_INDEX = {1_000_000: 0, 800_000: 1, 500_000: 2, 250_000: 3, 125_000: 4,
                    50_000: 6, 20_000: 7, 10_000: 8}
LSS_TIMEOUT_S = 0.05  # one LSS answer's wait (python canopen's default: 0.5 s a bit)
QUIET_S = 0.2  # listening for another master before anything is sent

#: An unanswered LSS request is sent again waiting this many times longer (the last: the
#: answer is taken for none).
PATIENCE = (1, 4, 10)
_T = TypeVar("_T")


def _found(result: tuple[bool, Any]) -> tuple[bool, Any]:
    """A fast scan that found nothing, as an error: :meth:`_Run._patiently` tries again."""
    if not result[0]:
        raise LssError("no answer to the fast scan")
    return result


class CommissionError(Exception):
    """Commissioning cannot start (the bus, another master): one line."""


@dataclass(frozen=True)
class DriveRow:
    """One drive: its identity, the node id it had (None: unknown, FFh: none), the one it
    has now (as it answered afterwards; None: not heard), and what was done."""

    identity: Identity
    before: int | None
    after: int | None
    wanted: int | None
    note: str

    @property
    def serial(self) -> int:
        return self.identity[3]


@dataclass(frozen=True)
class Commissioning:
    """What :func:`commission` found and did."""

    drives: tuple[DriveRow, ...]
    problems: tuple[str, ...]
    bit_timing: int | None = None  # bit/s stored where asked

    @property
    def ok(self) -> bool:
        return not self.problems


def wanted_ids(cfg: ChassisConfig) -> dict[int, int]:
    """Serial -> node id, as the config's wheels give them."""
    return {w.serial: w.node_id for w in cfg.wheels if w.serial is not None}


def bit_timing_index(bitrate: int) -> int:
    """The CiA 305 table-0 index of ``bitrate`` (bit/s); :class:`ConfigError` for a rate
    the table does not have."""
    try:
        return BIT_TIMING_INDEX[bitrate]
    except KeyError:
        rates = ", ".join(str(r) for r in sorted(BIT_TIMING_INDEX))
        raise ConfigError(f"LSS sets the bit rates {rates} (bit/s), not {bitrate}") from None


Progress = Callable[[str], None]


def commission(cfg: ChassisConfig, *, bitrate: int | None = None,
               lss_timeout_s: float = LSS_TIMEOUT_S, sdo_timeout_s: float = 0.3,
               progress: Progress | None = None) -> Commissioning:
    """Give every drive the node id the config names for its serial (see the module
    docstring). ``bitrate``: store this bit rate too (taken at the drives' next power-on).
    ``progress``: told of each step, one short line. :class:`CommissionError` when it
    cannot start (no bus; another master)."""
    say = progress or (lambda text: None)
    wanted = wanted_ids(cfg)
    timing = None if bitrate is None else bit_timing_index(bitrate)
    try:
        can_bus = CanBus(cfg.bus)
    except Exception as exc:
        raise CommissionError(str(exc)) from None
    with can_bus:
        network = can_bus.network
        lss = network.lss
        lss.RESPONSE_TIMEOUT = lss_timeout_s
        watch = MasterWatch(network)
        try:
            time.sleep(QUIET_S)
            other = watch.another_master()
            if other is not None:
                raise CommissionError(other)
            run = _Run(network, lss, watch, wanted, timing, sdo_timeout_s, say)
            run.unconfigured()
            run.misnumbered(cfg)
            run.reset_and_check()
            return Commissioning(tuple(run.rows), tuple(run.problems),
                                 None if timing is None else bitrate)
        finally:
            watch.close()


class _Run:
    """One commissioning's steps and what they found (see :func:`commission`)."""

    def __init__(self, network: canopen.Network, lss: canopen.lss.LssMaster, watch: MasterWatch,
                 wanted: Mapping[int, int], timing: int | None, sdo_timeout_s: float,
                 say: Progress) -> None:
        self.network, self.lss, self.watch = network, lss, watch
        self.wanted, self.timing, self.sdo_timeout_s, self.say = wanted, timing, sdo_timeout_s, say
        self.rows: list[DriveRow] = []
        self.problems: list[str] = []
        self.assigned: dict[int, Identity] = {}  # node id -> the drive given it

    def _problem(self, text: str) -> None:
        logger.info("commissioning: %s", text)
        self.problems.append(text)

    def _stopped_by_master(self) -> bool:
        other = self.watch.another_master()
        if other is not None and other not in self.problems:
            self._problem(other)
        return other is not None

    def unconfigured(self) -> None:
        """Fast scan for drives without a node id, one at a time: each found is given its
        node id, stored, and sent back to waiting (it takes the id and boots)."""
        lss = self.lss
        lss.send_switch_state_global(lss.WAITING_STATE)
        count = 0
        while not self._stopped_by_master():
            self.say(f"fast scan for drives without a node id ({count} found)")
            try:
                # A scan that found nothing, or whose last step failed (an answer that came
                # after the timeout reads as a bit of 1), again, waiting longer.
                found, ident = self._patiently(lambda: _found(lss.fast_scan()))
            except LssError:
                found, ident = False, None
            if not found:
                if count == 0:
                    self.say("no drive without a node id answered the fast scan")
                return
            count += 1
            identity: Identity = tuple(int(x) for x in ident)  # type: ignore[assignment]
            serial = identity[3]
            self.say(f"found serial 0x{serial:08X} ({_hex_identity(identity)})")
            if self._answers(lss.inquire_node_id) > 1:
                self._problem(f"two drives answer as serial 0x{serial:08X} "
                              f"({_hex_identity(identity)}): LSS cannot tell them apart; "
                              "give them their node ids one at a time (the other off the "
                              "bus) or each its own serial")
                self.rows.append(DriveRow(identity, UNCONFIGURED, None, self.wanted.get(serial),
                                          "two drives with this serial: left without id"))
                lss.send_switch_state_global(lss.WAITING_STATE)
                return  # both would answer every scan from here on
            node_id = self.wanted.get(serial)
            if node_id is None:
                self._problem(f"the drive with serial 0x{serial:08X} is in no [[wheel]] of the "
                              "config (serial = ...): it was left without a node id")
                self.rows.append(DriveRow(identity, UNCONFIGURED, None, None,
                                          "serial not in the config: left without id"))
                lss.send_switch_state_global(lss.WAITING_STATE)
                return  # it would be the one found again
            self._give(identity, UNCONFIGURED, node_id)

    def _patiently(self, call: Callable[[], _T]) -> _T:
        """``call()``, again with longer LSS timeouts (:data:`PATIENCE`) while it raises
        :class:`LssError`: a slave's answer may come late on a loaded bus or host."""
        lss = self.lss
        timeout = lss.RESPONSE_TIMEOUT
        try:
            for factor in PATIENCE[:-1]:
                lss.RESPONSE_TIMEOUT = timeout * factor
                try:
                    return call()
                except LssError:
                    logger.debug("LSS: no answer within %.2f s: again", lss.RESPONSE_TIMEOUT)
            lss.RESPONSE_TIMEOUT = timeout * PATIENCE[-1]
            return call()
        finally:
            lss.RESPONSE_TIMEOUT = timeout

    def _answers(self, request: Callable[[], object]) -> int:
        """How many LSS answers ``request`` got (two drives selected at once answer
        twice)."""
        before = self.watch.answers
        try:
            request()
        except LssError:
            return 0
        time.sleep(self.lss.RESPONSE_TIMEOUT)
        return self.watch.answers - before

    def _give(self, identity: Identity, before: int, node_id: int) -> None:
        """Configure the selected drive's node id (and bit timing), store, back to waiting."""
        lss = self.lss
        serial = identity[3]
        taken = self.assigned.get(node_id)
        if taken is not None:
            self._problem(f"node id {node_id} went to serial 0x{taken[3]:08X} already; "
                          f"serial 0x{serial:08X} was left as it was")
            self.rows.append(DriveRow(identity, before, None, node_id, "id taken: left as it was"))
            lss.send_switch_state_global(lss.WAITING_STATE)
            return
        self.say(f"serial 0x{serial:08X}: node id {node_id}")
        note = "given its node id"
        try:
            self._patiently(lambda: lss.configure_node_id(node_id))
            if self.timing is not None:
                timing = self.timing
                self._patiently(lambda: lss.configure_bit_timing(timing))
        except LssError as exc:
            self._problem(f"the drive with serial 0x{serial:08X} refused node id {node_id} ({exc})")
            self.rows.append(DriveRow(identity, before, None, node_id, "refused its node id"))
            lss.send_switch_state_global(lss.WAITING_STATE)
            return
        try:
            self._patiently(lss.store_configuration)
        except LssError as exc:
            self._problem(f"the drive with serial 0x{serial:08X} refused to store node id "
                          f"{node_id} ({_lss_error(exc)}): it has it until its next "
                          "power-on, no longer")
            note = "NOT STORED: lost at the next power-on"
        self.assigned[node_id] = identity
        lss.send_switch_state_global(lss.WAITING_STATE)
        if before not in (UNCONFIGURED, node_id):
            # A drive with a node id takes a new one at a reset communication (CiA 305).
            self.network.send_message(NMT_COB_ID,
                                      bytes([NmtCommand.RESET_COMMUNICATION, before]))
        self.rows.append(DriveRow(identity, before, None, node_id, note))

    def misnumbered(self, cfg: ChassisConfig) -> None:
        """The drives whose serial the config names that run with another node id (found
        by their identity, 1018h, over SDO): selected by identity and given theirs."""
        missing = {s for s in self.wanted if s not in {r.serial for r in self.rows}}
        if not missing or self._stopped_by_master():
            return
        self.say("looking for drives with a node id that is not theirs")
        seen: dict[int, int] = {}  # serial -> node id
        for node_id, identity in identities(self.network, self.sdo_timeout_s).items():
            serial = identity[3]
            if serial in seen and serial in self.wanted:
                self._problem(f"two drives answer as serial 0x{serial:08X} (nodes "
                              f"{seen[serial]} and {node_id}): LSS cannot tell them apart; "
                              f"node {node_id} was left as it was")
                continue
            seen[serial] = node_id
            if serial not in missing:
                continue
            missing.discard(serial)
            target = self.wanted[serial]
            if node_id == target:
                self.rows.append(DriveRow(identity, node_id, node_id, target, "had its node id"))
                continue
            self.say(f"serial 0x{serial:08X} runs as node {node_id}: selecting it")
            try:
                self._patiently(functools.partial(self.lss.send_switch_state_selective,
                                                  *identity))
            except LssError as exc:
                self._problem(f"the drive with serial 0x{serial:08X} (node {node_id}) did not "
                              f"answer LSS selection ({exc})")
                self.rows.append(DriveRow(identity, node_id, None, target, "no LSS answer"))
                continue
            self._give(identity, node_id, target)
        for serial in sorted(missing):
            node = self.wanted[serial]
            self._problem(f"no drive with serial 0x{serial:08X} (node {node} in the config) "
                          "answered")

    def reset_and_check(self) -> None:
        """Reset every drive given an id (NMT reset node), wait for its boot-up, and read
        back its serial: the row says the node id it answers with now."""
        if not self.assigned:
            if not self.rows and not self.problems:
                self._problem("no drive found: none without a node id answered LSS, and none "
                              "of the config's serials answered SDO")
            return
        for node_id in self.assigned:
            self.watch.watch_boot(node_id)
        sent = time.monotonic()
        for node_id in self.assigned:
            self.network.send_message(NMT_COB_ID, bytes([NmtCommand.RESET_NODE, node_id]))
        self.say("resetting the drives")
        deadline = sent + BOOT_WAIT_S
        while time.monotonic() < deadline and not all(
                self.watch.boots.get(n, 0) >= sent for n in self.assigned):
            time.sleep(0.02)
        found: dict[int, Identity] = {}
        while True:  # a drive slow to boot (or to answer) is asked again, a while
            left = [n for n, ident in self.assigned.items() if found.get(n) != ident]
            found.update(identities(self.network, self.sdo_timeout_s, left))
            if all(found.get(n) == i for n, i in self.assigned.items()) or \
                    time.monotonic() > deadline + BOOT_WAIT_S:
                break
            time.sleep(0.1)
        rows = []
        for row in self.rows:
            if row.wanted is None or self.assigned.get(row.wanted) != row.identity:
                rows.append(row)
                continue
            ident = found.get(row.wanted)
            if ident is None or ident[3] != row.serial:
                self._problem(f"the drive with serial 0x{row.serial:08X} did not come back as node "
                              f"{row.wanted} after its reset")
                rows.append(replace(row, note=row.note + "; not back after reset"))
            else:
                rows.append(replace(row, after=row.wanted))
        self.rows = rows


def _hex_identity(identity: Identity) -> str:
    v, p, r, s = identity
    return f"vendor 0x{v:08X}, product 0x{p:08X}, revision 0x{r:08X}, serial 0x{s:08X}"


def _lss_error(exc: LssError) -> str:
    text = str(exc)
    code = text.rsplit(" ", 1)[-1]
    why = {"1": "store not supported", "2": "storage media access error"}.get(code)
    return f"LSS error {code}: {why}" if why else text
