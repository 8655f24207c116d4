"""What a test, a demo or the fault console (:mod:`omnican.sim.console`) does to a
simulated drive: faults, silence, reboots, a slow boot or SDO server; a jammed,
pushed or lifted wheel, a following error, the supply voltage, the e-stop.

:class:`DriveFaults` holds these methods of :class:`~omnican.sim.drive.SimulatedDrive`
(``sim.drives[0].inject_fault(...)``, ``.stop_heartbeat()``, ``.reboot()``, ``.jam()``
...): each one changes the drive's parts (:class:`~omnican.sim.device.Device`, its
node side :class:`~omnican.sim.node.SimNode`) under the drive's lock, the motion up to
now left as it was.
"""

from __future__ import annotations

import math
import threading

from omnican.clock import Clock
from omnican.sim.axis import Axis
from omnican.sim.device import Device
from omnican.sim.health import DriveHealth
from omnican.sim.node import SimNode


class DriveFaults:
    """Fault injection and the wheel's conditions; a part of
    :class:`~omnican.sim.drive.SimulatedDrive`, whose parts these are."""

    lock: threading.RLock
    clock: Clock
    device: Device
    comm: SimNode
    axes: list[Axis]
    health: DriveHealth

    # ------------------------------------------------------------ the drive

    def inject_fault(self, code: int = 0x2310, axis: int = 0, persistent: bool = False) -> None:
        """Trip a fault: EMCY with ``code``, then FAULT REACTION ACTIVE -> FAULT.
        ``persistent``: its cause stays (a motor that has not cooled down): fault resets
        are refused until :meth:`clear_fault`."""
        with self.lock:
            self.device.advance(self.clock.now())
            group = self.axes[axis].group
            group.stage.fault_persists = persistent
            self.device.follow(group, group.stage.trip(code))

    def clear_fault(self, axis: int = 0) -> None:
        """The cause of a persistent fault is gone: the next fault reset clears it."""
        with self.lock:
            self.axes[axis].group.stage.fault_persists = False

    def hold_switched_on(self, held: bool = True, axis: int = 0) -> None:
        """The power stage cannot enable (no DC link voltage, safe torque off): enable
        operation is ignored, the drive stays SWITCHED ON."""
        with self.lock:
            self.axes[axis].group.stage.enable_held = held

    def act_on_arrival(self, on: bool = True) -> None:
        """Act on a controlword only as one arrives, as ros2_canopen's fake CiA 402 slave
        does: in OPERATION ENABLED the motors start at a controlword that arrives there
        (the enable command again), not at the one that enabled the drive. A master that
        writes the controlword only when it changes gets a drive that is enabled, takes
        every target and never moves; one that writes it every cycle, a drive that runs.
        Every power stage of the drive, from its next enabling on."""
        with self.lock:
            for group in self.device.groups:
                group.stage.on_arrival = on
                if not on:  # it acts on the controlword it holds: an enabled drive runs
                    group.stage.running = True
            self.device.motion.invalidate()


    def inject_following_error(self, counts: int = 5000, axis: int = 0) -> None:
        """The drive reports a following error: 60F4h reads ``counts`` and statusword
        bit 13 is set, until :meth:`clear_following_error`."""
        with self.lock:
            self.health.following_error[axis] = int(counts)

    def clear_following_error(self, axis: int = 0) -> None:
        with self.lock:
            self.health.following_error[axis] = None

    def set_supply(self, volts: float) -> None:
        """The supply (battery) voltage feeding the drive's DC link."""
        with self.lock:
            self.device.advance(self.clock.now())
            self.health.supply_v = float(volts)

    def estop(self, pressed: bool) -> None:
        """The e-stop: its input shows it (60FDh bit 16 by default) and, pressed, it
        takes the torque away (safe torque off): every power stage drops to SWITCH ON
        DISABLED and cannot be enabled until it is released."""
        with self.lock:
            self.device.advance(self.clock.now())
            self.health.estop_pressed = pressed
            for group in self.device.groups:
                self.device.follow(group, group.stage.safe_torque_off(pressed))
            self.comm.event_tpdos(self.clock.now())

    # ------------------------------------------------------------ the node

    def stop_heartbeat(self) -> None:
        """Stop producing heartbeats (the drive keeps working otherwise)."""
        with self.lock:
            self.comm.heartbeat.enabled = False

    def start_heartbeat(self, periodic: bool = False) -> None:
        """Produce heartbeats (again). ``periodic``: on the producer's period only, as
        lely's producer does (the first one period after 1017h is written, none at an NMT
        state change); else also at once on both (the default)."""
        with self.lock:
            self.comm.heartbeat.enabled = True
            self.comm.heartbeat_periodic = periodic

    def reboot(self) -> None:
        """Power-cycle: boot-up frame, OD defaults, position counters at their power-up value."""
        with self.lock:
            self.device.advance(self.clock.now())
            self.comm.boot(reset_node=True)

    def freeze(self) -> None:
        """Go silent: answer nothing, send nothing (a hung node). The motor keeps its demand."""
        with self.lock:
            self.comm.frozen = True

    def thaw(self) -> None:
        with self.lock:
            self.comm.frozen = False
            self.comm.heartbeat.last_sent = -1e9

    def slow_boot(self, seconds: float) -> None:
        """Answer an NMT reset with the boot-up ``seconds`` later (0: at once), answering
        SDOs meanwhile; a reset during that time starts the wait again."""
        if not (math.isfinite(seconds) and seconds >= 0):
            raise ValueError(f"a boot delay is 0 s or more, got {seconds}")
        with self.lock:
            self.comm.boot_delay_s = seconds

    def slow_sdo(self, seconds: float) -> None:
        """Answer each SDO request ``seconds`` after it came (0: at once)."""
        if not (math.isfinite(seconds) and seconds >= 0):
            raise ValueError(f"an SDO delay is 0 s or more, got {seconds}")
        with self.lock:
            self.comm.sdo_delay_s = seconds

    # ------------------------------------------------------------ the wheel

    def _condition(self, axis: int, **values: object) -> None:
        """Change what holds an axis (from now on: the motion up to now is as it was)."""
        with self.lock:
            self.device.advance(self.clock.now())
            ax = self.axes[axis]
            for name, value in values.items():
                setattr(ax, name, value)
            self.device.motion.invalidate()

    def jam(self, axis: int = 0) -> None:
        """The wheel cannot turn (a jammed roller, a wheel against a wall): it stands
        still while its drive pushes at its current limit."""
        self._condition(axis, jammed=True)

    def free(self, axis: int = 0) -> None:
        """The wheel turns again (no longer jammed, nor pushed)."""
        self._condition(axis, jammed=False, pushed_counts_s=None)

    def push(self, speed_m_s: float, axis: int = 0) -> None:
        """Something turns the wheel at ``speed_m_s`` at the rim whatever its drive does
        (a push, a runaway drive); :meth:`free` ends it."""
        self._condition(axis, pushed_counts_s=speed_m_s * self.health.counts_per_m[axis])

    def lift(self, axis: int = 0) -> None:
        """The wheel is off the ground: it turns as its drive says, on much less
        current, and no longer moves the base."""
        self._condition(axis, grounded=False)

    def land(self, axis: int = 0) -> None:
        """The wheel is back on the ground."""
        self._condition(axis, grounded=True)
