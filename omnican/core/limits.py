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

import itertools
import math
from dataclasses import dataclass

import numpy as np

from omnican.core.kinematics import OmniKinematics, Twist

# ---------------------------------------------------------------- what makes physical sense
#
# Values a front end, a script or a config may hand the library, bounded where they stop
# meaning anything for a wheeled base. A command beyond the limits is still taken (and
# limited: a Teleop panel's full stick asks for "as fast as allowed"); one beyond these
# bounds is a bug or an attack, and refused: at 1e308 the speed scaling overflows (three
# such commands move nothing, one drives at the wheel limit), a pose of 1e308 m leaves
# no bits for the motion added to it.

#: m/s and rad/s: no command, speed limit or wheel speed beyond this is physical.
MAX_SPEED_SENSE = 100.0
#: m/s^2 and rad/s^2 (about 10 g): no acceleration or deceleration beyond this.
MAX_ACCEL_SENSE = 100.0
#: m and rad: a pose beyond this (1000 km; an unwrapped heading of 160,000 turns) is not
#: a place the base can be, and its float has only 1e-10 m left for the motion after it.
MAX_POSE_SENSE = 1e6


def command_problem(vx: float, vy: float, wz: float) -> str | None:
    """Why a body velocity command (m/s, m/s, rad/s) makes no sense, or None: a NaN or
    an infinity, or a value beyond :data:`MAX_SPEED_SENSE`."""
    for name, value, unit in (("vx", vx, "m/s"), ("vy", vy, "m/s"), ("wz", wz, "rad/s")):
        if not math.isfinite(value):
            return f"{name} must be a finite number, got {value!r}"
        if abs(value) > MAX_SPEED_SENSE:
            return (f"{name} {value:.6g} {unit} is beyond any wheeled base (at most "
                    f"{MAX_SPEED_SENSE:g}; the configured limits cap what it drives at)")
    return None


def pose_problem(x: float, y: float, theta: float) -> str | None:
    """Why a pose (m, m, rad) cannot be the odometry's, or None."""
    for name, value, unit in (("x", x, "m"), ("y", y, "m"), ("theta", theta, "rad")):
        if not math.isfinite(value):
            return f"{name} must be a finite number, got {value!r}"
        if abs(value) > MAX_POSE_SENSE:
            return (f"{name} {value:.6g} {unit} is beyond {MAX_POSE_SENSE:g} {unit} (the "
                    "motion added to it would be lost to rounding)")
    return None


# ---------------------------------------------------------------- the stop in bounded time
#
# Every stop must end in bounded time, whatever the decelerations say. Where the bound
# comes from: when this host goes silent, each drive stops on its own with its quick-stop
# deceleration (6085h, or 604Ah in vl mode; abort option 6007h = quick stop), which
# omnican writes as twice the stop decelerations at the rim (drive/sdo_config.py). So both the
# base's stop ramp and the drives' own quick stop scale with chassis.stop_decel and
# stop_angular_decel: a tiny value makes *both* endless (at 1e-9 the quick stop rounds to
# 0 drive units: the drive never stops by itself either). The fastest the base can move
# is its speed limit: max_speed / max_angular_speed, or where those are unlimited, what
# max_wheel_speed at the rims allows (top_speeds). A ramp from there must end within
# MAX_STOP_S, so
#
#     stop_decel         >= top linear speed  / MAX_STOP_S
#     stop_angular_decel >= top angular speed / MAX_STOP_S
#
# (the limiter moves linear and angular by one common factor, so the stop takes the
# longer of the two times, and each is within the bound), and the drives' quick stop,
# at twice that, stops a wheel from max_wheel_speed within MAX_STOP_S / 2 (a wheel's rim
# speed is at most the body's linear speed plus its radius times the angular speed, and
# drive/sdo_config.py counts a radius of 0.5 m).
# MAX_STOP_S is 2 s: the defaults (2 x the accelerations, 1 m/s at the rims) stop the
# demo base from its top speed in 0.7 s linear, 0.9 s spinning; 2 s is three times that,
# room for a heavy base with gentle ramps, and still a stop a person beside the robot
# sees as one. The config refuses a deceleration below this floor; the limiter bounds
# its stop ramp to it whatever it is given (a VelocityLimits built in code, a live
# parameter), and closing the base waits for that bound, no longer, before disabling.

#: s: the longest a stop ramp may take from the fastest motion the limits allow.
MAX_STOP_S = 2.0


def top_speeds(limits: VelocityLimits, kinematics: OmniKinematics | None = None
               ) -> tuple[float, float]:
    """The fastest (linear m/s, angular rad/s) the limiter can ever output under
    ``limits``: the speed limits, the wheel limit's polytope (every wheel within
    max_wheel_speed, when ``kinematics`` are given), and :data:`MAX_SPEED_SENSE` (what a
    command may ask at most), whichever is lowest."""
    lin = min(limits.max_linear, MAX_SPEED_SENSE)
    ang = min(limits.max_angular, MAX_SPEED_SENSE)
    if kinematics is not None and math.isfinite(limits.max_wheel_speed):
        wl, wa = _wheel_polytope_top(kinematics.rows, limits.max_wheel_speed)
        lin, ang = min(lin, wl), min(ang, wa)
    return lin, ang


def _wheel_polytope_top(rows: tuple[tuple[float, float, float], ...], w: float
                        ) -> tuple[float, float]:
    """Max linear norm and max |wz| over the twists with every |row . t| <= w: both
    maxima of a convex function over a polytope are at a vertex, and each vertex is
    where three rows are at +-w."""
    a = np.asarray(rows, dtype=np.float64)
    best_lin = best_ang = 0.0
    for idx in itertools.combinations(range(len(rows)), 3):
        m = a[list(idx)]
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        inv = np.linalg.inv(m)
        for signs in itertools.product((-w, w), repeat=3):
            t = inv @ np.asarray(signs)
            if np.max(np.abs(a @ t)) <= w * (1 + 1e-9):
                best_lin = max(best_lin, math.hypot(float(t[0]), float(t[1])))
                best_ang = max(best_ang, abs(float(t[2])))
    return best_lin, best_ang


def stop_decel_floor(limits: VelocityLimits, kinematics: OmniKinematics | None = None
                     ) -> tuple[float, float]:
    """The lowest (linear m/s^2, angular rad/s^2) stop decelerations that stop the base
    from its fastest motion within :data:`MAX_STOP_S` (derivation above)."""
    lin, ang = top_speeds(limits, kinematics)
    return lin / MAX_STOP_S, ang / MAX_STOP_S


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
        self._kin = kinematics
        self._rows = kinematics.rows if kinematics is not None else ()
        self._last = (0.0, 0.0, 0.0)
        self.limits = limits
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
        # The speed caps: the limits', and never beyond sense, so that the output (and
        # with it the stop ramp below) stays bounded whatever a caller commands.
        self._caps = (min(limits.max_linear, MAX_SPEED_SENSE),
                      min(limits.max_angular, MAX_SPEED_SENSE))
        # The stop ramp, bounded whatever the limits say (see MAX_STOP_S); from the output
        # now too, in case the limits were lowered while it is above them.
        floor_lin, floor_ang = stop_decel_floor(limits, self._kin)
        vx, vy, wz = self._last
        self._stop_decel = (
            max(limits.stop_linear_decel, floor_lin, math.hypot(vx, vy) / MAX_STOP_S),
            max(limits.stop_angular_decel, floor_ang, abs(wz) / MAX_STOP_S))

    @property
    def stop_decel(self) -> tuple[float, float]:
        """The (linear m/s^2, angular rad/s^2) decelerations a stop ramps at: the limits',
        or the floor that ends it within :data:`MAX_STOP_S` where they are lower."""
        return self._stop_decel

    def stop_time_s(self) -> float:
        """How long a stop from the current output takes (at most :data:`MAX_STOP_S`)."""
        vx, vy, wz = self._last
        lin, ang = self._stop_decel
        return max(math.hypot(vx, vy) / lin, abs(wz) / ang)

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
        max_lin, max_ang = self._caps
        # 1. speed limits, one factor
        lin, limit = math.hypot(vx, vy), max_lin
        k = 1.0 if lin <= limit else limit / lin
        ang, limit = abs(wz), max_ang
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
        if vx == 0.0 and vy == 0.0 and wz == 0.0:  # stopping
            lin_a, ang_a = self._stop_decel
        else:
            lin_a, ang_a = lim.max_linear_accel, lim.max_angular_accel
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
