"""Heading from the wheels and a gyro together: a small Kalman filter on heading and gyro bias.

Omni wheels slip (their rollers give way, carpet and ramps make it worse) and a heading
integrated from the wheels alone drifts without bound. A gyro measures the yaw rate
directly but carries a bias (0.1 - 1 deg/s for a MEMS gyro) that integrates to a drift of
its own. :class:`HeadingFusion` fuses the two once per control cycle:

- **State** ``[theta, b]``: the fused heading (rad, continuous like the wheels') and the
  gyro's bias (rad/s), with their 2 x 2 covariance ``P``.
- **Yaw rate** each step: the gyro's (``g - b``) and the wheels' (``dtheta_w / dt``) are
  combined by inverse variance. The gyro's variance is its noise over the step plus what
  is not known of its bias (``P_bb``); the wheels' is a floor plus a slip share of each
  wheel's rim speed through the kinematics (slip grows with speed). The heading integrates
  the combined rate, and ``P`` is propagated with it (``F = [[1, -w_g dt], [0, 1]]``: the
  heading error is correlated with the bias error in proportion to the gyro's weight).
- **Outliers**: when the two rates differ by more than ``gate`` in Mahalanobis distance
  (``d^2 = (w_g - w_w)^2 / (var_g + var_w)``), the wheels are taken to slip and the step
  uses the gyro alone (robot_localization gates each measurement the same way). The
  disagreement is what :mod:`omnican.core.slip` watches.
- **Zero-velocity update**: while the base stands still (every wheel at rest and the
  command zero), the true yaw rate is zero, so the gyro's mean reading *is* its bias: a
  Kalman update of ``b`` with that measurement. Through the heading-bias correlation it
  also corrects the heading for what the old bias integrated while moving, and ``P``
  shrinks. Between stops the bias is a random walk (``bias_walk``), ``P_bb`` grows.
- **Fall back**: no IMU sample for ``stale_s`` (none configured, or one gone silent): the
  heading follows the wheels' step exactly, the heading's variance grows by the wheels'.

Why a Kalman filter rather than a complementary filter, by measurement
(``bench/bench_fusion.py``: the inputs of ten 1 m squares with a wheel slipping 10 % and
a gyro biased 0.5 deg/s replayed through both, the bias learnt standing still alike): a
complementary filter's one crossover lets a slip that lasts longer than its time
constant into the heading in full, and on an omni base slip lasts as long as the base
moves; it ended 469, 447 and 263 deg off with time constants of 1, 10 and 100 s, this
filter 0.4 deg. It weighs the two by their variances each step (the wheels count for
less the faster they turn), gates the wheels out where they disagree, and learns the
bias only where it is observable cleanly (standing still). It costs a few microseconds
more a step than the complementary filter (about 9 us a cycle in the loop, at 100 Hz and
1 kHz alike): the 2 x 2 algebra written out in plain floats, no numpy call per cycle.

The position integrates each wheel step's body displacement ``(dx, dy)`` with the fused
heading, through the same SE(2) exponential as :class:`~omnican.core.odometry.Odometry`,
so with a gyro that agrees with the wheels the fused pose *is* the wheels' pose.

Pure module: no I/O, no clock (the caller gives the time).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from omnican.core.imu import ImuSample
from omnican.core.kinematics import OmniKinematics
from omnican.core.odometry import Odometry
from omnican.core.slip import SlipDetector, slipping_wheel
from omnican.core.wheel_odometry import WheelOdometry

STILL_M_S = 0.001  # every wheel slower than this (m/s, over the speed window) ...
STILL_S = 0.1  # ... for this long, the command zero: standing still (zero-velocity update)
#: chi-square(1) at 99.9 %: a yaw-rate disagreement beyond this many variances is an outlier
GATE_D2 = 10.83


@dataclass(frozen=True)
class FusionParams:
    """What the filter assumes of its inputs (SI units).

    ``gyro_noise``: 1-sigma of one gyro sample (rad/s). ``bias_walk``: the bias's random
    walk (rad/s per sqrt(s)). ``bias0``: 1-sigma of the bias before anything was learnt
    (rad/s). ``wheel_rate_floor``: 1-sigma of the wheels' yaw rate at rest (rad/s).
    ``wheel_slip``: 1-sigma slip of a wheel as a fraction of its rim speed. ``gate``:
    Mahalanobis d^2 beyond which the wheels' rate is rejected. ``stale_s``: no IMU sample
    for this long: fall back to the wheels. ``max_rate``: gyro readings beyond it (rad/s)
    are out of any real gyro's range and dropped. ``wheel_quantum``: the rim travel of one
    encoder count (m; the coarsest wheel's). ``tau_s``: the wheels' and the gyro's
    disagreement is low-passed over this time before it is gated (a slip lasts, the
    encoders' and the gyro's noise does not). ``slip_corr_s``: how long a wheel's slip
    lasts (its correlation time): a slip is not white noise that averages out over the
    steps, so the wheels' rate is weighed as if its variance were ``2 slip_corr_s / dt``
    times its one-step variance."""

    gyro_noise: float = 0.005
    bias_walk: float = 0.0001
    bias0: float = 0.02
    wheel_rate_floor: float = 0.005
    wheel_slip: float = 0.01
    gate: float = GATE_D2
    stale_s: float = 0.2
    max_rate: float = 35.0
    wheel_quantum: float = 1e-4
    tau_s: float = 0.04
    slip_corr_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("gyro_noise", "bias_walk", "bias0", "wheel_rate_floor", "wheel_slip",
                     "gate", "stale_s", "max_rate", "wheel_quantum", "tau_s", "slip_corr_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"fusion {name} must be a positive number, got {value!r}")


@dataclass(frozen=True)
class FusedState:
    """The fused odometry as of one step: pose ``(x, y, theta)`` (m, m, rad), its
    heading's variance ``var_theta`` (rad^2), the gyro's bias and its variance, the fused
    yaw rate (rad/s), whether the IMU is live (False: the wheels alone, fall back), and
    whether the last step rejected the wheels' rate (they slip)."""

    x: float
    y: float
    theta: float
    var_theta: float
    bias: float
    var_bias: float
    yaw_rate: float
    imu_live: bool
    wheels_rejected: bool


class HeadingFusion:
    """The wheels' steps and a gyro's samples fused into heading and pose (see the module
    docstring). ``rows``: the kinematics' wheel rows (rim speed = a vx + b vy + c wz per
    wheel, :attr:`OmniKinematics.rows`), ``wz_of``: each wheel's share of the body yaw rate
    (the forward matrix's last row, :attr:`OmniKinematics.forward_rows` [2]).

    :meth:`step` once a cycle. Not thread-safe: the loop's."""

    __slots__ = ("_diff", "_imu_t", "_last_w", "_lasting", "_n", "_pbb", "_ptb", "_ptt", "_rate",
                 "_rows", "_share2", "_step_t", "_sum", "_t", "_wz_of", "b", "isolate", "params",
                 "rate", "rejected", "samples", "slip", "theta", "wheel_speeds", "x", "y")

    def __init__(self, rows: Sequence[Sequence[float]], wz_of: Sequence[float],
                 params: FusionParams | None = None,
                 pose: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        p = self.params = params if params is not None else FusionParams()
        self._rows = tuple((float(a), float(b), float(c)) for a, b, c in rows)
        self._wz_of = tuple(float(c) for c in wz_of)
        if len(self._rows) != len(self._wz_of):
            raise ValueError(f"{len(self._rows)} wheel rows and {len(self._wz_of)} yaw shares")
        self.x, self.y, self.theta = pose
        self.b = 0.0
        self._ptt, self._ptb, self._pbb = 0.0, 0.0, p.bias0 * p.bias0
        self._t: float | None = None  # the last step's time
        self._step_t: float | None = None  # the last wheel step's time
        self._sum, self._n = 0.0, 0  # the gyro's samples since then: their sum and number
        self._imu_t = -math.inf  # the newest IMU sample's time
        self._rate = 0.0  # the newest gyro rate (mean of the last samples), bias not removed
        self.rate = 0.0  # the fused yaw rate of the last step
        self.rejected = False
        self.samples = 0  # gyro samples fused
        self._share2 = sum(c * c for c in self._wz_of)
        self._diff = 0.0  # the wheels' yaw rate less the gyro's, low-passed
        self._last_w = 0.0  # the wheels' yaw rate of the last step
        self._lasting = 0.0  # the disagreement's lasting variance, low-passed as it is
        self.slip = SlipDetector()
        #: more than three wheels: the measured rim speeds, and slip.slipping_wheel on the
        #: kinematics, read when a slip starts to name the wheel (None: not named)
        self.wheel_speeds: Callable[[], Sequence[float]] | None = None
        self.isolate: Callable[[Sequence[float]], int | None] | None = None

    # ------------------------------------------------------------ reading

    @property
    def gyro_rate(self) -> float:
        """The gyro's newest yaw rate, its bias removed (rad/s)."""
        return self._rate - self.b

    @property
    def var_theta(self) -> float:
        return self._ptt

    @property
    def var_bias(self) -> float:
        return self._pbb

    @property
    def xyt(self) -> tuple[float, float, float]:
        return self.x, self.y, self.theta

    def imu_live(self, now: float) -> bool:
        """A gyro sample came within ``stale_s`` of ``now``."""
        return now - self._imu_t <= self.params.stale_s

    def state(self, now: float) -> FusedState:
        return FusedState(self.x, self.y, self.theta, self._ptt, self.b, self._pbb,
                          self.rate, self.imu_live(now), self.rejected)

    def reset(self, pose: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """The pose is ``pose`` from now on, known exactly; the bias is kept."""
        self.x, self.y, self.theta = pose
        self._ptt = self._ptb = 0.0

    # ------------------------------------------------------------ the step

    def step(self, now: float, samples: Sequence[ImuSample],
             wheel_step: tuple[float, float, float] | None, still: bool) -> None:
        """One cycle at ``now``: the IMU ``samples`` that came since the last step,
        ``wheel_step`` the wheels' body displacement (dx, dy, dtheta in m, m, rad) since the
        last step (None: no new complete set of wheel samples), ``still``: the base stands
        still (wheels at rest, command zero)."""
        last_t = self._t
        self._t = now
        p = self.params
        n = 0
        total = 0.0
        newest = self._imu_t
        limit = p.max_rate
        for s in samples:
            g = s.yaw_rate
            if -limit < g < limit:  # also drops NaN
                total += g
                n += 1
                newest = max(newest, s.t)
        if n:
            self._rate = total / n
            self._imu_t = newest
            self.samples += n
            self._sum += total
            self._n += n
        live = now - self._imu_t <= p.stale_s
        if last_t is not None and 0.0 < now - last_t < 1.0:
            self._pbb += p.bias_walk * p.bias_walk * (now - last_t)
        if still and live and n:
            self._zero_velocity_update(self._rate, p.gyro_noise * p.gyro_noise / n)
        if wheel_step is None:
            return
        # The wheels' step spans the time since their last one: so does the gyro's mean.
        last_step = self._step_t
        self._step_t = now
        dt = now - last_step if last_step is not None else 0.0
        if not 0.0 < dt < 1.0:
            dt = 0.0
        n = self._n
        gyro = self._sum / n if n else self._rate
        self._sum, self._n = 0.0, 0
        dx, dy, dw = wheel_step
        if not live or dt == 0.0:
            # The wheels alone (fall back): their step, their variance.
            dth = dw
            self.rejected = False
            self._ptt += self._wheel_var(dx, dy, dw, dt or 1.0) * (dt * dt)
            self.rate = dw / dt if dt else 0.0
            self._diff = self._last_w = self._lasting = 0.0
            self.slip.update(now, 0.0, False)
        elif still:
            dth = dw  # standing still: the wheels' step (about zero), nothing to weigh
            self.rate = 0.0
            self.rejected = False
            self._diff = self._last_w = self._lasting = 0.0
            self.slip.update(now, 0.0, False)
        else:
            w_w = dw / dt
            w_g = gyro - self.b
            # White parts: the gyro's noise and the encoders' counts over this step; what
            # persists: the unknown bias, the wheels' slip, and the rate's change over a
            # step (the gyro's samples and the wheels' SYNC are not taken at one instant).
            noise_g = p.gyro_noise * p.gyro_noise / max(n, 1)
            quantum = p.wheel_quantum / dt
            noise_w = quantum * quantum * self._share2 / 6.0
            change = w_w - self._last_w
            self._last_w = w_w
            var_w = self._wheel_var(dx, dy, dw, dt) + change * change
            var_g = noise_g + self._pbb
            # The disagreement, low-passed over tau_s (a slip lasts, noise does not).
            alpha = dt / (p.tau_s + dt)
            e = self._diff = self._diff + alpha * (w_w - w_g - self._diff)
            # Its variance: the white parts shrink by the low-pass; the lasting ones pass
            # it as the difference does (a spike of acceleration fades from both alike).
            lasting = self._lasting = self._lasting + alpha * (self._pbb + var_w - self._lasting)
            var_e = alpha / (2.0 - alpha) * (noise_g + noise_w) + lasting
            d2 = e * e / var_e
            self.slip.update(now, e, d2 > p.gate, self.wheel_speeds, self.isolate)
            if d2 > p.gate:  # the wheels slip: the gyro alone
                k_g, rate, var_rate = 1.0, w_g, noise_g
                self.rejected = True
            else:
                # Slip persists: weighed as a white noise of the same effect on the heading.
                var_w = var_w * (2.0 * p.slip_corr_s / dt) + noise_w
                k_g = var_w / (var_g + var_w)
                rate = w_g + (w_w - w_g) * (1.0 - k_g)
                var_rate = k_g * k_g * noise_g + (1.0 - k_g) * (1.0 - k_g) * var_w
                self.rejected = False
            self.rate = rate
            dth = rate * dt
            # P <- F P F' + Q, F = [[1, -k_g dt], [0, 1]], Q = diag(var_rate dt^2, 0)
            f = -k_g * dt
            ptb, pbb = self._ptb, self._pbb
            self._ptt += 2.0 * f * ptb + f * f * pbb + var_rate * dt * dt
            self._ptb = ptb + f * pbb
        self._move(dx, dy, dth)

    def _wheel_var(self, dx: float, dy: float, dw: float, dt: float) -> float:
        """Variance of the wheels' yaw rate over a step (rad^2/s^2): the floor plus each
        wheel's slip share of its rim speed, through its share of the yaw rate."""
        slip = self.params.wheel_slip
        var = self.params.wheel_rate_floor ** 2
        vx, vy, wz = dx / dt, dy / dt, dw / dt
        for (a, b, c), share in zip(self._rows, self._wz_of, strict=True):
            e = slip * (a * vx + b * vy + c * wz) * share
            var += e * e
        return var

    def _zero_velocity_update(self, z: float, r: float) -> None:
        """Kalman update with the gyro's mean reading ``z`` (variance ``r``) as the bias:
        the base stands still, its true yaw rate is zero. H = [0, 1]."""
        ptt, ptb, pbb = self._ptt, self._ptb, self._pbb
        s = pbb + r
        k_t, k_b = ptb / s, pbb / s
        innovation = z - self.b
        self.theta += k_t * innovation
        self.b += k_b * innovation
        self._ptt = ptt - k_t * ptb
        self._ptb = ptb - k_t * pbb
        self._pbb = pbb - k_b * pbb

    def _move(self, dx: float, dy: float, dw: float) -> None:
        """Compose the body step (dx, dy, dw) onto the pose (Odometry.step's SE(2) exp)."""
        if -1e-4 < dw < 1e-4:
            t2 = dw * dw
            a, b = 1.0 - t2 / 6.0 + t2 * t2 / 120.0, dw / 2.0 - dw * t2 / 24.0
        else:
            a, b = math.sin(dw) / dw, (1.0 - math.cos(dw)) / dw
        lx, ly = a * dx - b * dy, b * dx + a * dy
        th = self.theta
        c, s = math.cos(th), math.sin(th)
        self.x += c * lx - s * ly
        self.y += s * lx + c * ly
        self.theta = th + dw


class FusionConfig(Protocol):
    """What :meth:`FusedOdometry.configured` reads of the ``[fusion]`` table
    (:class:`omnican.config.FusionSettings`)."""

    @property
    def gyro_noise(self) -> float: ...
    @property
    def bias_walk(self) -> float: ...
    @property
    def wheel_slip(self) -> float: ...
    @property
    def slip_warn_s(self) -> float: ...
    @property
    def stop_on_slip(self) -> bool: ...
    @property
    def stop_on_imu_stale(self) -> bool: ...


class FusedOdometry:
    """The control loop's side of the fusion: a :class:`HeadingFusion` fed with the steps
    of the wheels' odometry (``odometry``, the one pose the wheels own, and
    ``wheel_odometry``, its speed window), and what a slip or a silent IMU does.

    :meth:`step` once a cycle (only on a base with an IMU); :attr:`values` is what the
    snapshot carries, :attr:`warnings` what the status adds. ``slip_warn_s``: a slip this
    long warns; ``stop_on_slip`` / ``stop_on_imu_stale``: and :meth:`step` returns a reason
    to stop the base."""

    __slots__ = ("_seen", "_since", "_stale_warned", "_still_since", "fusion", "odometry",
                 "stop_on_imu_stale", "stop_on_slip", "values", "warnings", "wheel_odometry")

    def __init__(self, kinematics: OmniKinematics, params: FusionParams, odometry: Odometry,
                 wheel_odometry: WheelOdometry, slip_warn_s: float = 0.5,
                 stop_on_slip: bool = False, stop_on_imu_stale: bool = False) -> None:
        self.fusion = fusion = HeadingFusion(kinematics.rows, kinematics.forward_rows[2], params,
                                             odometry.xyt)
        fusion.slip.warn_s = slip_warn_s
        if kinematics.num_wheels > 3:
            matrix = kinematics.matrix
            fusion.wheel_speeds = wheel_odometry.speeds
            fusion.isolate = lambda speeds: slipping_wheel(matrix, speeds, fusion.gyro_rate)
        self.odometry = odometry
        self.wheel_odometry = wheel_odometry
        self.stop_on_slip = stop_on_slip
        self.stop_on_imu_stale = stop_on_imu_stale
        self._seen = odometry.last_step  # the wheels' step fused last (by identity)
        self._since: float | None = None  # the first step's time
        self._stale_warned = False
        self._still_since: float | None = None  # standing still since (None: moving)
        #: (x, y, theta, var_theta, bias, var_bias, yaw_rate, imu_live, slipping)
        self.values: tuple[float, float, float, float, float, float, float, bool, bool] = (
            *odometry.xyt, 0.0, 0.0, params.bias0 ** 2, 0.0, False, False)
        self.warnings: tuple[str, ...] = ()

    @classmethod
    def configured(cls, kinematics: OmniKinematics, odometry: Odometry,
                   wheel_odometry: WheelOdometry, settings: FusionConfig,
                   imu: object = None) -> FusedOdometry:
        """As the ``[fusion]`` table ``settings`` says; ``imu``: the ``[imu]`` table, whose
        ``stale_s`` wins (an IMU attached in code, without one: ``FusionParams``'). The
        encoders' resolution (the coarsest wheel's count) is the wheels' quantum."""
        given = getattr(imu, "stale_s", None)
        stale_s = float(given if given is not None else
                        getattr(settings, "stale_s", FusionParams.stale_s))
        quantum = max(1.0 / abs(w.counts_per_m) for w in wheel_odometry.counters.wheels)
        params = FusionParams(gyro_noise=settings.gyro_noise, bias_walk=settings.bias_walk,
                              wheel_slip=settings.wheel_slip, stale_s=stale_s,
                              wheel_quantum=quantum)
        return cls(kinematics, params, odometry, wheel_odometry, settings.slip_warn_s,
                   settings.stop_on_slip, settings.stop_on_imu_stale)

    def reset(self, pose: tuple[float, float, float]) -> None:
        """The pose is ``pose`` from now on (the wheels' odometry was reset to it too)."""
        self.fusion.reset(pose)

    def step(self, now: float, samples: Sequence[ImuSample], commanded_zero: bool) -> str | None:
        """Fuse this cycle's IMU ``samples`` with the wheels' newest step (if one came);
        ``commanded_zero``: the limited command is zero. Returns a reason to stop the base
        (configured), else None."""
        fusion = self.fusion
        step = self.odometry.last_step
        wheel_step = None
        if step is not self._seen:
            self._seen = wheel_step = step
        # Standing still: commanded zero, every wheel below STILL_M_S, for STILL_S (the
        # motors' last creep after braking would read as the gyro's bias).
        if commanded_zero and self.wheel_odometry.settled(STILL_M_S):
            if self._still_since is None:
                self._still_since = now
            still = now - self._still_since >= STILL_S
        else:
            self._still_since = None
            still = False
        fusion.step(now, samples, wheel_step, still)
        if self._since is None:
            self._since = now
        slip = fusion.slip
        live = now - max(fusion._imu_t, self._since) <= fusion.params.stale_s
        self.values = (fusion.x, fusion.y, fusion.theta, fusion._ptt, fusion.b, fusion._pbb,
                       fusion.rate, live, slip.active is not None)
        stop = None
        warnings: tuple[str, ...] = ()
        if not live:
            silent = now - max(fusion._imu_t, self._since)
            warnings = (f"IMU silent for {silent:.1f} s: the odometry is the wheels' alone",)
            if not self._stale_warned:
                self._stale_warned = True
                if self.stop_on_imu_stale:
                    stop = f"the IMU went silent ({silent:.1f} s without a sample)"
        else:
            self._stale_warned = False
        if slip.warning is not None:
            warnings = (*warnings, slip.warning)
            if self.stop_on_slip and slip.active is not None and stop is None:
                stop = slip.warning
        self.warnings = warnings
        return stop
