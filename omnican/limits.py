"""Body velocity and acceleration limiting that keeps the direction of motion.

Each step, the commanded twist is:

1. scaled by one common factor so that the linear speed (vector norm) and the
   angular speed are within their limits: the path's curvature is kept;
2. desaturated at the wheels (one common factor so no wheel exceeds its maximum
   rim speed) when kinematics are given. Doing this on the *target*, before the
   acceleration limit, keeps every output feasible: the set of twists whose wheel
   speeds are within the limit is convex, so each step between two feasible twists
   stays feasible;
3. approached from the previous output with one common factor on the change, so
   that the linear (norm) and angular accelerations stay within their limits. A stop
   command (zero twist) uses the deceleration limits instead, which are usually larger.

Pure module: no I/O, no CAN imports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from omnican.kinematics import OmniKinematics, Twist


@dataclass(frozen=True)
class VelocityLimits:
    """Limits on the body motion. Linear values are vector norms (m/s, m/s^2);
    angular values are rad/s and rad/s^2. ``inf`` disables a limit."""

    max_linear: float = math.inf
    max_angular: float = math.inf
    max_linear_accel: float = math.inf
    max_angular_accel: float = math.inf
    stop_linear_decel: float = math.inf
    stop_angular_decel: float = math.inf
    max_wheel_speed: float = math.inf

    def __post_init__(self) -> None:
        for name in (
            "max_linear",
            "max_angular",
            "max_linear_accel",
            "max_angular_accel",
            "stop_linear_decel",
            "stop_angular_decel",
            "max_wheel_speed",
        ):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or math.isnan(value) or value <= 0:
                raise ValueError(f"{name} must be a positive number, got {value!r}")


def _ratio(limit: float, value: float) -> float:
    """Largest factor k <= 1 with k * value <= limit."""
    if value <= limit:
        return 1.0
    return limit / value


def clamp_twist(twist: Twist, limits: VelocityLimits) -> Twist:
    """Step 1: scale ``twist`` by one factor to respect the speed limits."""
    k = min(
        _ratio(limits.max_linear, twist.linear_speed),
        _ratio(limits.max_angular, abs(twist.wz)),
    )
    return twist if k == 1.0 else twist.scaled(k)


def desaturate_twist(twist: Twist, kinematics: OmniKinematics, max_wheel_speed: float) -> Twist:
    """Step 2: scale ``twist`` by one factor so no wheel exceeds ``max_wheel_speed``."""
    if math.isinf(max_wheel_speed):
        return twist
    vx, vy, wz = twist.vx, twist.vy, twist.wz
    # Plain floats: this runs every control cycle, on three to six numbers.
    peak = max(abs(a * vx + b * vy + c * wz) for a, b, c in kinematics.rows)
    k = _ratio(max_wheel_speed, peak)
    return twist if k == 1.0 else twist.scaled(k)


def limit_step(current: Twist, target: Twist, dt: float, limits: VelocityLimits) -> Twist:
    """Step 3: move from ``current`` towards ``target`` within the acceleration limits."""
    stopping = target.is_zero()
    lin = limits.stop_linear_decel if stopping else limits.max_linear_accel
    ang = limits.stop_angular_decel if stopping else limits.max_angular_accel
    dvx, dvy, dwz = target.vx - current.vx, target.vy - current.vy, target.wz - current.wz
    k = min(_ratio(lin * dt, math.hypot(dvx, dvy)), _ratio(ang * dt, abs(dwz)))
    if k == 1.0:
        return target
    return Twist(current.vx + k * dvx, current.vy + k * dvy, current.wz + k * dwz)


class VelocityLimiter:
    """Stateful limiter: call :meth:`step` once per control cycle.

    Args:
        limits: the limits to apply.
        kinematics: when given, targets are desaturated at the wheels
            against ``limits.max_wheel_speed``.
    """

    def __init__(self, limits: VelocityLimits, kinematics: OmniKinematics | None = None) -> None:
        self.limits = limits
        self._kin = kinematics
        self._rows = kinematics.rows if kinematics is not None else ()
        self._last = (0.0, 0.0, 0.0)
        # The last command and its feasible target (steps 1 and 2 depend on nothing else).
        self._feasible: tuple[tuple[float, float, float], tuple[float, float, float]] | None = \
            None

    @property
    def limits(self) -> VelocityLimits:
        return self._limits

    @limits.setter
    def limits(self, limits: VelocityLimits) -> None:
        self._limits = limits
        self._feasible = None

    @property
    def output(self) -> Twist:
        """The last twist returned by :meth:`step`."""
        return Twist(*self._last)

    def reset(self, twist: Twist | None = None) -> None:
        """Set the current output (e.g. to zero after the drives were stopped)."""
        self._last = (twist.vx, twist.vy, twist.wz) if twist is not None else (0.0, 0.0, 0.0)

    def target(self, command: Twist) -> Twist:
        """Steps 1 and 2: the feasible twist the limiter will approach for ``command``."""
        if not command.is_finite():
            raise ValueError(f"command contains a non-finite value: {command}")
        twist = clamp_twist(command, self.limits)
        if self._kin is not None:
            twist = desaturate_twist(twist, self._kin, self.limits.max_wheel_speed)
        return twist

    def step(self, command: Twist, dt: float) -> Twist:
        """Limit ``command`` for a cycle of ``dt`` seconds; returns the twist to apply."""
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"dt must be a non-negative number, got {dt!r}")
        if not command.is_finite():
            raise ValueError(f"command contains a non-finite value: {command}")
        return Twist(*self.step_xyz(command.vx, command.vy, command.wz, dt))

    def step_xyz(self, vx: float, vy: float, wz: float,
                 dt: float) -> tuple[float, float, float]:
        """:meth:`step` on plain floats, unchecked (finite command, dt >= 0): the control
        loop's form. Same three steps, no objects made. Returns the previous result (the
        same tuple) while neither the command nor the output changes."""
        command = (vx, vy, wz)
        feasible = self._feasible
        if feasible is not None and feasible[0] == command:
            target = feasible[1]
            last = self._last
            if last == target:
                return last  # holding the target: step 3 would return it unchanged
            vx, vy, wz = target
        else:
            vx, vy, wz = self._steps_1_2(vx, vy, wz)
            self._feasible = (command, (vx, vy, wz))
        return self._step_3(vx, vy, wz, dt)

    def _steps_1_2(self, vx: float, vy: float, wz: float) -> tuple[float, float, float]:
        # The factors are _ratio's, written out: this runs every cycle of the loop.
        lim = self._limits
        # 1. speed limits, one factor
        lin, limit = math.hypot(vx, vy), lim.max_linear
        k = 1.0 if lin <= limit else limit / lin
        ang, limit = abs(wz), lim.max_angular
        if ang > limit and limit / ang < k:
            k = limit / ang
        if k != 1.0:
            vx, vy, wz = vx * k, vy * k, wz * k
        # 2. wheel desaturation, one factor
        limit = lim.max_wheel_speed
        if self._rows and limit != math.inf:
            peak = 0.0
            for a, b, c in self._rows:
                v = abs(a * vx + b * vy + c * wz)
                peak = max(peak, v)
            if peak > limit:
                k = limit / peak
                vx, vy, wz = vx * k, vy * k, wz * k
        return vx, vy, wz

    def _step_3(self, vx: float, vy: float, wz: float, dt: float) -> tuple[float, float, float]:
        # 3. acceleration limits on the change, one factor
        lim = self._limits
        cx, cy, cw = self._last
        stopping = vx == 0.0 and vy == 0.0 and wz == 0.0
        lin_a = lim.stop_linear_decel if stopping else lim.max_linear_accel
        ang_a = lim.stop_angular_decel if stopping else lim.max_angular_accel
        dvx, dvy, dwz = vx - cx, vy - cy, wz - cw
        step, limit = math.hypot(dvx, dvy), lin_a * dt
        k = 1.0 if step <= limit else limit / step
        step, limit = abs(dwz), ang_a * dt
        if step > limit and limit / step < k:
            k = limit / step
        out = (vx, vy, wz) if k == 1.0 else (cx + k * dvx, cy + k * dvy, cw + k * dwz)
        self._last = out
        return out


def longest_stop_s(limits: VelocityLimits, kinematics: OmniKinematics) -> float:
    """The longest a stop ramp at ``limits``' stop decelerations can take (s), from any
    twist the base may have (every wheel within ``max_wheel_speed``, the body within its
    speed limits): one common factor brings linear and angular speed to zero together,
    so the slower of the two decides. An upper bound (each body speed bounded on its own)."""
    w = limits.max_wheel_speed
    rx, ry, rw = kinematics.forward_rows
    linear = min(limits.max_linear, w * math.hypot(sum(map(abs, rx)), sum(map(abs, ry))))
    angular = min(limits.max_angular, w * sum(map(abs, rw)))
    return max(linear / limits.stop_linear_decel, angular / limits.stop_angular_decel)
