"""What the drives report and what the wheels do, checked a few dozen times a second on
the loop thread by the supervisor (never by the control cycle itself):

- each wheel against its target (:mod:`omnican.core.tracking`), from the targets and
  measured speeds the cycle already has, and the following error a drive reports
  (statusword bit 13 in pv and csv);
- each wheel's current against its siblings' (:mod:`omnican.core.lift`): one off the ground
  (or without its roller) warns, or stops the base (``chassis.lifted_wheel``);
- each wheel of a stopped base (latched, or a drive out of OPERATION ENABLED) whose
  drive is still energised: one that turns, or whose drive pushes against its zero
  target, for ``tracking_time_s`` once the longest stop ramp is over, is disabled and
  named;
- the e-stop input (``[estop]``): pressed, it is the stop's reason, and ``recover()``
  refuses while it is held;
- the battery (``[power]``, :mod:`omnican.chassis.battery`): a warning, then a controlled stop;
- the CAN controller (:mod:`omnican.protocol.can_state`): bus-off is a stop's reason, and
  ``recover()`` refuses until the controller is restarted;
- the health values themselves (:mod:`omnican.drive.health`): the round-robin SDO reads
  are sent from here, and what each wheel shows is made here (a
  :class:`~omnican.plan.health_fields.WheelHealth` per wheel, a
  :class:`~omnican.chassis.state.StatusChecks`), handed to every snapshot until the next
  check.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from typing import Protocol

from omnican.chassis.battery import BatteryMonitor, base_voltage
from omnican.chassis.state import CheckResults, StatusChecks, nothing_checked
from omnican.config import ChassisConfig
from omnican.core.lift import LiftDetector
from omnican.core.limits import longest_stop_s
from omnican.core.tracking import ZERO_M_S, StandstillWatch, TrackingDetector
from omnican.drive import DriveNode
from omnican.drive.health import NodeHealth
from omnican.io.bus import CanBus
from omnican.plan.health import HealthRead
from omnican.plan.health_fields import HEALTH_FIELDS, WheelHealth
from omnican.protocol import cia402
from omnican.protocol.cia402 import Mode, State
from omnican.protocol.object_map import Obj

logger = logging.getLogger("omnican.chassis")


class Latches(Protocol):
    """What the checks read of the NodeSupervisor (omnican.chassis.supervisor), and how they
    stop the base: the supervisor owns these checks and hands itself to each check."""

    latched: str | None
    recovering: bool
    configuring: set[int]
    offline: set[int]
    closed: bool

    def latch(self, reason: str) -> None: ...

    def latch_cause(self, reason: str) -> None: ...

    def latch_also(self, reason: str) -> None: ...

TRACKING_HZ = 10.0  # tracking checks per second (at most the loop rate)
_ENABLED = State.OPERATION_ENABLED
_ENERGISED = (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE)
_SLIPPAGE_MODES = (int(Mode.PROFILE_VELOCITY), int(Mode.CYCLIC_SYNC_VELOCITY))
#: (targets, measured speeds, wheels without a fresh sample, every drive enabled)
Speeds = Callable[[], tuple[Sequence[float], Sequence[float], Sequence[int], bool]]
Key = tuple[int, int]


class _Estop:
    """The e-stop as one node shows it: a health read's bit, or its statusword's."""

    def __init__(self, node: DriveNode) -> None:
        layout = node.layout
        assert layout.estop is not None and layout.estop_entry is not None
        self.node = node
        self.bit, self.active_low = layout.estop.bit, layout.estop.active_low
        entry = layout.estop_entry
        self.key = (entry.index, entry.subindex)
        self.statusword = entry.obj is Obj.STATUSWORD
        self.where = (f"node {node.node_id} {entry.name} ({entry.address}) bit {self.bit}"
                      + (" clear" if self.active_low else ""))

    def pressed(self, now: float) -> bool | None:
        """None: not known (nothing fresh from the drive)."""
        if self.statusword:
            raw = self.node.stages[0].statusword_value
        else:
            raw = self.node.health.raw(self.key, now)
        if raw is None:
            return None
        return bool(raw >> self.bit & 1) != self.active_low


class ChassisChecks:
    """See the module docstring. ``speeds`` (set by the base) reads the cycle's targets
    and measured speeds."""

    def __init__(self, cfg: ChassisConfig, nodes: list[DriveNode], bus: CanBus) -> None:
        c = cfg.chassis
        self.nodes = nodes
        self._bus = bus
        # Tracking a few times within tracking_time_s; the values, e-stop and battery as
        # often as the drives report them; the round-robin SDO reads as their plan says.
        self._tracking_period = 1.0 / min(TRACKING_HZ, c.rate_hz)
        self._values_period = 1.0 / c.health_rate_hz
        self._next_tracking = self._next_values = -math.inf
        self.next_at = -math.inf  # the next check is due then (the supervisor looks)
        self.speeds: Speeds | None = None
        axes = sorted(((a, n) for n in nodes for a in n.axes), key=lambda an: an[0].wheel_index)
        self._wheels = [(a.wheel_index, n, a.wheel.axis) for a, n in axes]
        self._stages = [(a.wheel_index, n, a.wheel.axis, a.stage) for a, n in axes]
        self._all_fresh = [True] * len(axes)
        self.tracking = TrackingDetector(len(axes), c.tracking_error, c.tracking_time_s,
                                         c.tracking_lag_s, c.tracking_ratio)
        # A stopped base: a drive's own ramp (set from the stop decelerations) ends within
        # the longest stop ramp, its measurement within the lag; from then on, as running.
        self.standstill = StandstillWatch(
            len(axes), c.tracking_error, c.tracking_time_s,
            longest_stop_s(cfg.limits(), cfg.kinematics()) + c.tracking_lag_s)
        self._named: set[int] = set()  # wheels named since the last recover()
        self.lifted_wheel = c.lifted_wheel
        self.lift = LiftDetector(len(axes))
        # Per wheel, how hard its drive pushes, % of its rating: the torque (6077h), else
        # the current where it is 6078h (per mille of the rated current).
        self._loads: list[tuple[NodeHealth, HealthRead | None, Key | None]] = []
        for a, n in axes:
            torque: HealthRead | None = None
            current: Key | None = None
            for read in n.health.plan.reads:
                if a.wheel_index in read.wheels and read.quantity == "torque":
                    torque = read
                elif (a.wheel_index in read.wheels and read.quantity == "current"
                      and read.entry.obj is Obj.CURRENT_ACTUAL):
                    current = read.key
            self._loads.append((n.health, torque, current))
        # Per wheel: its node's values and, per field of WheelHealth that its drive gives,
        # (name, key, SI per unit; None: the scale found at startup; 0: the raw integer).
        self._wheel_reads: list[tuple[NodeHealth, tuple[tuple[str, Key, float | None],
                                                        ...]]] = []
        for a, n in axes:
            by_quantity = {r.quantity: r for r in n.health.plan.reads
                           if a.wheel_index in r.wheels}
            self._wheel_reads.append((n.health, tuple(
                (f.name, r.key, 0.0 if f.register else r.scale) for f in HEALTH_FIELDS
                if (r := by_quantity.get(f.quantity)) is not None)))
        self._voltages = [(n.health, r) for n in nodes for r in n.health.plan.reads
                          if r.quantity == "voltage"]
        self.battery = BatteryMonitor(cfg.power) if cfg.power is not None else None
        self._estops = [_Estop(n) for n in nodes
                        if n.layout.estop is not None and n.layout.estop_entry is not None]
        #: why recover() may not clear the stop now (an e-stop held, bus-off), or None
        self.estop_held: str | None = None
        self.bus_off: str | None = None
        #: what each snapshot carries until the next check
        self.values: CheckResults = nothing_checked(len(axes))

    def check(self, now: float, sup: Latches) -> None:
        """What is due at ``now`` (loop thread, once ``next_at`` has come); ``sup``
        latches what it finds."""
        next_at = math.inf
        for node in self.nodes:
            health = node.health
            if health.plan.sdo:
                if node.node_id not in sup.configuring and node.node_id not in sup.offline:
                    health.poll(now, self._bus.send)
                next_at = min(next_at, health.next_poll_at)
        if now >= self._next_tracking:
            self._next_tracking = max(self._next_tracking + self._tracking_period, now)
            self._check_controller(sup)
            self._check_tracking(now, sup)
        if now >= self._next_values:
            self._next_values = max(self._next_values + self._values_period, now)
            self._refresh(now, sup)
        self.next_at = min(next_at, self._next_tracking, self._next_values)

    def _refresh(self, now: float, sup: Latches) -> None:
        """The values each snapshot carries, the e-stop, the battery."""
        wheel_values = []
        for health, reads in self._wheel_reads:
            values, scales, oldest = health.values, health.scales, now - health.stale_after_s
            fresh: dict[str, float | int | None] = {}  # by WheelHealth's field names
            for name, key, per_unit in reads:
                got = values.get(key)
                if got is None or got[1] < oldest:
                    continue
                scale = scales.get(key) if per_unit is None else per_unit
                fresh[name] = got[0] if scale == 0.0 else None if scale is None else \
                    got[0] * scale
            wheel_values.append(WheelHealth.of(fresh))
        lift_warnings = self._check_lift(now, sup, wheel_values) \
            if self.lifted_wheel != "off" else ()
        pressed = self._check_estop(now, sup)
        volts = base_voltage([h.si(r, now) for h, r in self._voltages]) if self._voltages \
            else None
        warnings: tuple[str, ...] = lift_warnings
        battery = self.battery
        level = None
        if battery is not None:
            battery.update(now, volts)
            # Held for as long as it lasts, not only when reached: a recover() that cleared
            # the stop meanwhile is stopped again.
            if battery.cut and sup.latched is None and not sup.closed:
                sup.latch(battery.cutoff_reason())
            warning = battery.warning()
            if warning:
                warnings = (*warnings, warning)
            level = "cutoff" if battery.cut else "low" if battery.low else "ok"
        can = self._bus.controller.state
        seen = can.error_frames > 0
        self.values = CheckResults(tuple(wheel_values), StatusChecks(
            can_state=can.state if seen else None, can_tx_errors=can.tx_errors,
            can_rx_errors=can.rx_errors, can_error_frames=can.error_frames, estop=pressed,
            battery_v=volts, battery=level, warnings=warnings))

    # ------------------------------------------------------------ the checks

    def _check_lift(self, now: float, sup: Latches,
                    wheel_values: list[WheelHealth]) -> tuple[str, ...]:
        """Each wheel's current against its siblings' while the base runs; the warnings
        of the wheels found off the ground."""
        speeds = self.speeds
        lift = self.lift
        if speeds is None:
            return ()
        _, measured, stale, all_enabled = speeds()
        if not (all_enabled and sup.latched is None and not sup.recovering and
                not sup.offline and not sup.configuring and not sup.closed):
            lift.paused()
            return ()
        currents = [h.current_a for h in wheel_values]
        known = [None if i in stale else v for i, v in enumerate(measured)]
        for finding in lift.update(now, known, currents):
            _, node, axis = self._wheels[finding.wheel]
            reason = finding.describe(node.node_id, axis)
            if self.lifted_wheel == "stop":
                sup.latch(reason)
            else:
                logger.warning("%s", reason)
        out = []
        for lifted in lift.lifted.values():
            _, node, axis = self._wheels[lifted.wheel]
            out.append(lifted.describe(node.node_id, axis))
        return tuple(out)

    def _check_estop(self, now: float, sup: Latches) -> bool:
        held = None
        for estop in self._estops:
            if estop.pressed(now):
                held = f"e-stop pressed ({estop.where})"
                break
        if held is not None and (self.estop_held is None or sup.latched is None):
            sup.latch_cause(held)
        elif held is None and self.estop_held is not None:
            logger.warning("e-stop released: recover() starts the base again")
        self.estop_held = held
        return held is not None

    def _check_controller(self, sup: Latches) -> None:
        state = self._bus.controller.state
        if state.bus_off and (self.bus_off is None or sup.latched is None):
            self.bus_off = (f"CAN bus-off: the controller left the bus after too many errors "
                            f"({state.describe()}); the interface's restart-ms brings it back")
            sup.latch_cause(self.bus_off)
        elif not state.bus_off and self.bus_off is not None:
            logger.warning("CAN controller restarted (%s): recover() starts the base again",
                           state.describe())
            self.bus_off = None

    def _check_tracking(self, now: float, sup: Latches) -> None:
        speeds = self.speeds
        if speeds is None:
            return
        targets, measured, stale, all_enabled = speeds()
        running = (all_enabled and sup.latched is None and not sup.recovering and
                   not sup.offline and not sup.configuring and not sup.closed)
        fresh = [i not in stale for i in range(len(self._wheels))] if stale else self._all_fresh
        for finding in self.tracking.update(now, targets, measured, fresh, running):
            _, node, axis = self._wheels[finding.wheel]
            if finding.zero_target:  # it ignores a zero target: take its torque away
                for stage in node.stages:
                    stage.set_goal(State.SWITCH_ON_DISABLED)
            sup.latch(finding.describe(node.node_id, axis))
            return
        if running:
            self._check_following_error(now, sup)
        elif not sup.closed and not sup.recovering:
            self._check_standstill(now, sup, targets, measured, fresh)
        elif self._named or sup.recovering:
            self.standstill.reset()

    def _load_pct(self, wheel: int, now: float) -> float | None:
        health, torque, current = self._loads[wheel]
        if torque is not None:
            pct = health.si(torque, now)
            if pct is not None:
                return pct
        if current is not None:
            raw = health.raw(current, now)
            if raw is not None:
                return raw / 10.0
        return None

    def _check_standstill(self, now: float, sup: Latches, targets: Sequence[float],
                          measured: Sequence[float], fresh: Sequence[bool]) -> None:
        """The base is stopped: a wheel whose drive is still energised turns, or its drive
        pushes, for longer than a stop takes. Its drive is disabled, the wheel named (in
        the stop's reason: after the first one if the base was already held stopped)."""
        watched, loads = [], []
        busy = sup.configuring or sup.offline
        for index, node, _axis, stage in self._stages:
            watch = (stage.state in _ENERGISED and abs(targets[index]) < ZERO_M_S and
                     index not in self._named and
                     not (busy and (node.node_id in sup.configuring or
                                    node.node_id in sup.offline)))
            watched.append(watch)
            loads.append(self._load_pct(index, now) if watch else None)
        for finding in self.standstill.update(now, watched, measured, fresh, loads):
            _, node, axis = self._wheels[finding.wheel]
            for stage in node.stages:
                stage.set_goal(State.SWITCH_ON_DISABLED)
            self._named.add(finding.wheel)
            reason = finding.describe(node.node_id, axis)
            if sup.latched is None:
                sup.latch(reason)
            else:
                sup.latch_also(reason)

    def _check_following_error(self, now: float, sup: Latches) -> None:
        for index, node, axis, stage in self._stages:
            sw = stage.statusword_value
            if (sw is None or not sw & cia402.SW_OMS_13 or stage.state is not _ENABLED or
                    stage.mode_value not in (*_SLIPPAGE_MODES, None) or
                    int(node.mode) not in _SLIPPAGE_MODES):
                continue
            value = ""
            for r in node.health.plan.reads:
                if r.quantity == "following_error" and index in r.wheels:
                    raw = node.health.raw(r.key, now)
                    if raw is not None:
                        value = f", {r.entry.name} {raw}"
            where = f"node {node.node_id}" + (f" axis {axis}" if axis else "")
            sup.latch(f"wheel {index} ({where}) not following its target: its drive reports a "
                      f"following error (statusword bit 13{value})")
            return

    # ------------------------------------------------------------ recover

    def recover_refused(self) -> str | None:
        """Why the base may not be recovered now, or None."""
        if self.estop_held:
            return f"{self.estop_held}: release it first"
        if self.bus_off:
            return "the CAN controller is bus-off: it must be restarted first (restart-ms)"
        if self.battery is not None and self.battery.cut:
            return self.battery.warning()
        return None

    def recovered(self) -> None:
        """recover() began: nothing is held against any wheel."""
        self.tracking.reset()
        self.standstill.reset()
        self._named.clear()
        self.lift.reset()
