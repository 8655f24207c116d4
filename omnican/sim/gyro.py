"""The simulated base's gyro: the true yaw rate as a real MEMS gyro measures it, sent on
the simulated bus through the configured IMU's DBC message.

:class:`GyroModel` (pure) is the sensor: the true rate (the rate of the true pose's
heading between two readings), plus a bias that starts at ``bias_deg_s`` and wanders as
a random walk (``drift_deg_s`` per square root of a second), plus white noise
(``noise_deg_s``), turned into the IMU's own frame by its mounting; its random numbers
are the same run after run (``noise_stream``). :class:`SimulatedGyro` samples the ground
truth at ``rate_hz`` (on the simulator's housekeeping timer, or a task of its own on a
lock-step clock) and sends what the model reads, encoded by cantools
into the ``[imu]`` table's message (and its acceleration message, from the true
twist's change), in the DBC signal's own unit: what ``omnican.io.imu`` decodes on the
host's side is what a real IMU of that DBC would send. The accelerations carry no
noise; the readings saturate at the signals' ranges, as a sensor's do.
"""

from __future__ import annotations

import logging
import math
import random
import threading
from collections.abc import Callable
from typing import Any

import can

from omnican.clock import Clock
from omnican.config import ChassisConfig, ImuSettings, SimGyro
from omnican.config.imu import dbc_imu
from omnican.core.imu import ImuMount
from omnican.core.kinematics import Twist
from omnican.core.odometry import Pose2D

logger = logging.getLogger(__name__)

_DEG = math.pi / 180.0


class GyroModel:
    """A gyro of ``spec`` mounted as ``mount``: :meth:`read` turns the true yaw rate
    (rad/s, base frame) into the reading in the IMU's frame (rad/s)."""

    def __init__(self, spec: SimGyro, mount: ImuMount) -> None:
        self.spec = spec
        self.mount = mount
        self._rng = random.Random(spec.noise_stream)
        self.bias = spec.bias_deg_s * _DEG  # rad/s, now

    def read(self, true_rate: float, dt: float) -> float:
        """One reading ``dt`` seconds after the last: the bias walks first."""
        spec = self.spec
        if spec.drift_deg_s and dt > 0:
            self.bias += self._rng.gauss(0.0, spec.drift_deg_s * _DEG * math.sqrt(dt))
        noise = self._rng.gauss(0.0, spec.noise_deg_s * _DEG) if spec.noise_deg_s else 0.0
        # The bias and noise are the sensor's own: they add in the IMU's frame.
        return self.mount.from_base(true_rate)[0] + self.bias + noise


class SimulatedGyro:
    """Sends the gyro of ``spec`` as the IMU of ``imu`` (``source = "can"``) would, every
    ``1 / spec.rate_hz`` of ``clock``: :meth:`tick` is the simulator's housekeeping hook.
    ``true_pose`` and ``true_twist`` read the ground truth; ``network`` is the simulated
    drives' (its bus and its send lock). :meth:`silence` stops it sending (an IMU gone
    quiet), :meth:`resume` starts it again."""

    def __init__(self, imu: ImuSettings, spec: SimGyro, network: Any, clock: Clock,
                 true_pose: Callable[[], Pose2D], true_twist: Callable[[], Twist]) -> None:
        dbc = dbc_imu(imu)
        mount = ImuMount(imu.mount_yaw_deg if spec.mount_yaw_deg is None
                         else spec.mount_yaw_deg, imu.upside_down)
        self.model = GyroModel(spec, mount)
        self.mount = mount
        self.imu = imu
        self.period_s = 1.0 / spec.rate_hz
        self._network = network
        self._clock = clock
        self._true_pose = true_pose
        self._true_twist = true_twist
        self._rate = dbc.rate_message
        self._accel = dbc.accel_message
        self._rate_per_unit = dbc.rate_factor
        self._accel_per_unit = dbc.accel_factor
        self._lock = threading.Lock()
        self._last: tuple[float, float, Twist] | None = None  # (t, theta, twist)
        self._next = -math.inf
        self.silent = not spec.enabled
        self.sent = 0
        self.send_errors = 0

    def silence(self) -> None:
        self.silent = True

    def resume(self) -> None:
        with self._lock:
            self.silent = False
            self._last = None  # a rate across the silence would be stale

    def tick(self, now: float) -> None:
        """Send a reading if one is due at ``now``."""
        with self._lock:
            # Due half a period early at the latest: a timer that ticks at about the
            # gyro's own rate (the control loop's, when it runs the drives) must not skip
            # every other reading for a tick that came a little early.
            if now < self._next - self.period_s / 2:
                return
            behind = now - self._next > self.period_s
            self._next = now + self.period_s if behind else self._next + self.period_s
            if self.silent:
                return
            pose, twist = self._true_pose(), self._true_twist()
            last, self._last = self._last, (now, pose.theta, twist)
            if last is None or now <= last[0]:
                return  # the first reading only seeds the rate
            dt = now - last[0]
            true_rate = (pose.theta - last[1]) / dt
            reading = self.model.read(true_rate, dt)
            ax = (twist.vx - last[2].vx) / dt - twist.wz * twist.vy
            ay = (twist.vy - last[2].vy) / dt + twist.wz * twist.vx
            _, imu_ax, imu_ay = self.mount.from_base(true_rate, ax, ay)
            frames = self._frames(reading, imu_ax, imu_ay)
        for frame in frames:
            self._send(frame)

    def _frames(self, rate: float, ax: float, ay: float) -> list[can.Message]:
        imu = self.imu
        rate_values = {imu.yaw_rate: rate / self._rate_per_unit}
        accel_values: dict[str | None, float] = {}
        if self._accel is not None:
            accel_values = {imu.accel_x: ax / self._accel_per_unit,
                            imu.accel_y: ay / self._accel_per_unit}
        if self._accel is self._rate:
            return [_frame(self._rate, {**rate_values, **accel_values})]
        frames = [_frame(self._rate, rate_values)]
        if self._accel is not None:
            frames.append(_frame(self._accel, accel_values))
        return frames

    def _send(self, msg: can.Message) -> None:
        network = self._network
        try:
            with network.send_lock:
                bus = network.bus
                if bus is None:
                    return
                bus.send(msg)
            self.sent += 1
        except (can.CanError, OSError, RuntimeError, ValueError) as exc:
            self.send_errors += 1
            if self.send_errors == 1:
                logger.warning("simulated gyro: sending failed: %s", exc)


def _frame(message: Any, given: dict[str | None, float]) -> can.Message:
    """``message`` with the ``given`` signals (physical values, clamped to the signals'
    ranges) and every other signal at its lowest raw value's physical value."""
    values: dict[str, float] = {}
    for signal in message.signals:
        value = given.get(signal.name)
        if value is None:
            value = signal.minimum if signal.minimum is not None else signal.offset
        else:
            if signal.minimum is not None:
                value = max(value, signal.minimum)
            if signal.maximum is not None:
                value = min(value, signal.maximum)
        values[signal.name] = value
    data = message.encode(values, scaling=True, padding=True, strict=False)
    return can.Message(arbitration_id=message.frame_id,
                       is_extended_id=bool(message.is_extended_frame), data=data)


def attach_gyro(cfg: ChassisConfig, network: Any, scheduler: Any, clock: Clock,
                pose: Callable[[], Pose2D], twist: Callable[[], Twist],
                ) -> tuple[SimulatedGyro | None, object | None]:
    """A CAN ``[imu]``'s gyro on the simulated bus, as ``[sim.gyro]`` says (default: a
    perfect one at 100 Hz), and its clock task (None: it runs on the drives' timer);
    (None, None) without a CAN ``[imu]``."""
    imu = cfg.imu
    if imu is None or imu.source != "can":
        return None, None
    spec = cfg.sim.gyro if cfg.sim is not None else None
    gyro = SimulatedGyro(imu, spec if spec is not None else SimGyro(), network, clock,
                         pose, twist)
    if clock.lockstep:  # a task of its own: its rate, whatever the drives' tick
        return gyro, clock.every(gyro.period_s, gyro.tick)
    scheduler.add(gyro.tick)  # on the drives' timer (the control loop's, when it runs them)
    return gyro, None
