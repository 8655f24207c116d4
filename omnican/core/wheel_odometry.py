"""Wheel odometry from encoder counters: the one owner of the counter fold, the speed
window and the measured twist.

:class:`EncoderCounters` folds each wheel's raw counter samples into continuous counts
(a wrap of the counter is not a jump; a restart after a reboot continues the travel);
:class:`WheelOdometry` integrates the travel of each complete set of samples into the
pose (an :class:`~omnican.core.odometry.Odometry` it feeds) and keeps the window that
measured wheel speeds and the body twist average over. The control loop
(:class:`omnican.chassis.cycle.ControlCycle`) and the recording decoder
(:func:`omnican.record.replay.decode`) both read counters through these classes, so a
replayed recording reads them as the live loop did.

Samples are read from objects the drive layer writes (:class:`CounterSample`: the TPDO
handler leaves the newest raw value and the SYNC it belongs to). :meth:`WheelOdometry.integrate`
runs every control cycle (100 Hz - 1 kHz): it is written out (no call per wheel), makes
only the values it keeps (the travel list, the window's tuples), and its objects have
``__slots__``. It calls the pose's :meth:`Odometry.step` rather than being an Odometry:
one type runs that code, so CPython's specialised attribute access holds (a simulator's
ground-truth Odometry in the same process would otherwise de-specialise it).

Pure module: no I/O.
"""

from __future__ import annotations

import collections
from collections.abc import Collection, Sequence
from typing import Protocol

from omnican.core.odometry import Odometry

#: Measured wheel speeds and body twist average over this window (s).
SPEED_WINDOW_S = 0.1


class CounterSample(Protocol):
    """Where the newest sample of one wheel's position counter is left (written by the
    drive's receive handler, read by the loop)."""

    raw: int | None  # the counter as read (None: no sample yet)
    epoch: int  # the SYNC it was taken for
    restarts: int  # times the counter restarted (a reboot); raised by whoever sees it


class CounterSampleSlot:
    """Where one wheel's newest counter sample is left, as a plain object: a
    :class:`CounterSample` for decoders and tests (a drive's own is its receive state)."""

    __slots__ = ("epoch", "raw", "restarts")

    def __init__(self, raw: int | None = None, epoch: int = -1) -> None:
        self.raw = raw
        self.epoch = epoch
        self.restarts = 0


class WheelCounter:
    """One wheel's counter as :class:`EncoderCounters` folds it. Written by its
    :class:`EncoderCounters` only; ``counts`` (continuous) may be read by anyone."""

    __slots__ = ("counts", "counts_per_m", "half_span", "last_raw", "restarts", "sample")

    def __init__(self, sample: CounterSample, bits: int, counts_per_m: float) -> None:
        self.sample = sample
        self.half_span = 1 << (bits - 1)  # half the counter's span: the largest step read
        self.counts_per_m = counts_per_m
        self.counts = 0.0  # continuous counts since the first sample
        self.last_raw: int | None = None  # the sample folded last (None: the next seeds)
        self.restarts = sample.restarts  # the sample's restarts, as of the last fold


class EncoderCounters:
    """The position counters of N wheels, folded into continuous counts and travel.

    ``samples[i]`` is where wheel i's samples arrive, ``bits[i]`` its counter's width
    and ``counts_per_m[i]`` its resolution (counts per metre at the rim, signed: the
    wheel's position_scale). The step from one sample to the next is taken modulo the
    counter's span, as the shortest way round, so a wrap is not a jump; the first sample,
    and the first after a restart (``sample.restarts`` raised: the drive rebooted and its
    counter restarted), only seed: the travel continues where it was."""

    __slots__ = ("wheels",)

    def __init__(self, samples: Sequence[CounterSample], bits: Sequence[int],
                 counts_per_m: Sequence[float]) -> None:
        if not len(samples) == len(bits) == len(counts_per_m):
            raise ValueError(f"{len(samples)} samples, {len(bits)} counter widths and "
                             f"{len(counts_per_m)} scales: one of each per wheel")
        self.wheels = tuple(WheelCounter(s, b, float(c))
                            for s, b, c in zip(samples, bits, counts_per_m, strict=True))

    def fold(self, epoch: int) -> list[float] | None:
        """Fold the samples of SYNC ``epoch``; returns each wheel's travel (m), or None
        when a wheel has no sample of that SYNC (the wheels before it are folded: folding
        the same sample again changes nothing). Each cycle: written out."""
        travel: list[float] = []
        for w in self.wheels:
            sample = w.sample
            raw = sample.raw
            if raw is None or sample.epoch != epoch:
                return None
            last = w.last_raw
            restarts = sample.restarts
            if restarts != w.restarts:  # the counter restarted: this sample only seeds
                w.restarts = restarts
                last = None
            if raw != last:
                w.last_raw = raw
                if last is not None:
                    half = w.half_span
                    w.counts += (raw - last + half) % (half << 1) - half
            travel.append(w.counts / w.counts_per_m)
        return travel

    def counts(self) -> list[float]:
        """Each wheel's continuous counts."""
        return [w.counts for w in self.wheels]


def fold_counter(counts: float, last_raw: int | None, raw: int, bits: int) -> float:
    """Continuous counts after the raw sample ``raw`` of a ``bits``-wide counter, the
    previous being ``last_raw`` (None: the first sample, or the first after a reboot:
    the counts stay where they are); :class:`EncoderCounters`' fold of one sample."""
    sample = CounterSampleSlot(last_raw, 0)
    counters = EncoderCounters((sample,), (bits,), (1.0,))
    counters.wheels[0].counts = counts
    if last_raw is not None:
        counters.fold(0)
    sample.raw, sample.epoch = raw, 1
    counters.fold(1)
    return counters.wheels[0].counts


_ZERO = (0.0, 0.0, 0.0)


class WheelOdometry:
    """Odometry read from encoder counters: the counters (``counters``), the pose they
    drive (``odometry``, an :class:`Odometry` whose :meth:`~Odometry.step` it calls: the
    one pose, which may be reset or read as usual), the speed window and the twist
    measured over it.

    :meth:`integrate` folds the counters and integrates every complete set of samples.
    The measured speeds are the travel since the latest set at least ``window_s`` older
    (or the oldest kept) over the time between: SYNC timing jitter averages out.
    :attr:`window` and :attr:`measured` are replaced whole, never changed in place (a
    snapshot may keep them)."""

    __slots__ = ("_body_sum", "_history", "_window_s", "counters", "measured", "odometry",
                 "window")

    def __init__(self, odometry: Odometry, counters: EncoderCounters,
                 window_s: float = SPEED_WINDOW_S) -> None:
        n = odometry.num_wheels
        if len(counters.wheels) != n:
            raise ValueError(f"expected {n} wheel counters, got {len(counters.wheels)}")
        self.odometry = odometry
        self.counters = counters
        self._window_s = window_s
        #: (travel now, travel at the window's start, its span in s): rim speeds are
        #: their difference over the span (made by whoever reads them)
        self.window: tuple[list[float], list[float], float] = ([0.0] * n, [0.0] * n, 1.0)
        #: the body twist over the window (vx m/s, vy m/s, wz rad/s)
        self.measured: tuple[float, float, float] = _ZERO
        # (SYNC time, travel, body displacement summed since seeding) of each complete set
        self._history: collections.deque[tuple[float, list[float], tuple[float, float, float]]] \
            = collections.deque()
        self._body_sum = _ZERO

    def integrate(self, epoch: int, t: float) -> bool:
        """Fold the samples of SYNC ``epoch``, sent at ``t`` (s), and integrate them if
        every wheel has one; False (nothing integrated) if not. Each cycle."""
        # EncoderCounters.fold, written out (each cycle: no call, no second loop).
        travel: list[float] = []
        for w in self.counters.wheels:
            sample = w.sample
            raw = sample.raw
            if raw is None or sample.epoch != epoch:
                return False
            last = w.last_raw
            restarts = sample.restarts
            if restarts != w.restarts:  # the counter restarted: this sample only seeds
                w.restarts = restarts
                last = None
            if raw != last:
                w.last_raw = raw
                if last is not None:
                    half = w.half_span
                    w.counts += (raw - last + half) % (half << 1) - half
            travel.append(w.counts / w.counts_per_m)
        moved = self.odometry.step(travel)
        history = self._history
        if moved is None:  # seeded (the first set, or the first after a reseed)
            self._body_sum = _ZERO
            history.clear()
            history.append((t, travel, _ZERO))
            return True
        # The body displacement over the window is the sum of the steps over it (the
        # forward kinematics is linear): one running sum, no second product.
        dx, dy, dw = moved
        sx, sy, sw = self._body_sum
        body = self._body_sum = (sx + dx, sy + dy, sw + dw)
        history.append((t, travel, body))
        window_s = self._window_s
        while len(history) > 2 and t - history[1][0] >= window_s:
            history.popleft()
        t0, travel0, body0 = history[0]
        if t > t0:
            span = t - t0
            self.window = (travel, travel0, span)
            self.measured = ((body[0] - body0[0]) / span, (body[1] - body0[1]) / span,
                             (body[2] - body0[2]) / span)
        return True

    def forget_speeds(self, wheels: Collection[int]) -> None:
        """``wheels`` (by index) have no known speed: they read 0, the others keep
        theirs, the measured twist is 0, and the window restarts with the next set."""
        travel, travel0, span = self.window
        self.window = ([0.0 if i in wheels else v for i, v in enumerate(travel)],
                       [0.0 if i in wheels else v for i, v in enumerate(travel0)], span)
        self.measured = _ZERO
        self._history.clear()

    def speeds(self) -> list[float]:
        """Measured rim speeds (m/s), by wheel index."""
        travel, travel0, span = self.window
        return [(a - b) / span for a, b in zip(travel, travel0, strict=True)]

    def settled(self, below_m_s: float) -> bool:
        """Every wheel's measured speed below ``below_m_s`` (m/s)."""
        travel, travel0, span = self.window
        return all(abs(a - b) < below_m_s * span for a, b in zip(travel, travel0, strict=True))
