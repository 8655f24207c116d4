"""The least-squares fit of a correction to recordings and their measured end poses.

Gauss-Newton least squares of the end poses predicted by integrating the recorded
counts with candidate factors against measured end poses (3 equations per recording).
Pure module: numpy only, no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from omnican.analysis.calibration.correction import Correction, scaled_kinematics
from omnican.config import ChassisConfig
from omnican.core.kinematics import OmniKinematics
from omnican.core.odometry import wrap_angle

FloatArray = npt.NDArray[np.float64]

# ---------------------------------------------------------------- odometry, vectorised


def _sinc_terms(w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Vectorised (sin w / w, (1 - cos w) / w), with the series near 0 (as odometry.py)."""
    small = np.abs(w) < 1e-4
    safe = np.where(small, 1.0, w)
    w2 = w * w
    a = np.where(small, 1.0 - w2 / 6.0 + w2 * w2 / 120.0, np.sin(safe) / safe)
    b = np.where(small, w / 2.0 - w * w2 / 24.0, (1.0 - np.cos(safe)) / safe)
    return a, b


def integrate(travel: npt.ArrayLike, kin: OmniKinematics) -> FloatArray:
    """Poses (M, 3) from cumulative wheel travel (M, N), starting at the origin: what
    :class:`omnican.core.odometry.Odometry` gives update by update (SE(2) exponential)."""
    arr = np.asarray(travel, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != kin.num_wheels:
        raise ValueError(f"travel must be (M, {kin.num_wheels}), got shape {arr.shape}")
    out = np.zeros((arr.shape[0], 3))
    if arr.shape[0] < 2:
        return out
    body = np.diff(arr, axis=0) @ kin.forward_matrix.T
    dx, dy, dw = body[:, 0], body[:, 1], body[:, 2]
    theta = np.concatenate([[0.0], np.cumsum(dw)])
    a, b = _sinc_terms(dw)
    lx, ly = a * dx - b * dy, b * dx + a * dy
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    out[1:, 0] = np.cumsum(c * lx - s * ly)
    out[1:, 1] = np.cumsum(s * lx + c * ly)
    out[:, 2] = theta
    return out


# ---------------------------------------------------------------- least-squares fit


@dataclass(frozen=True)
class FitRun:
    """One recording: continuous encoder counts per complete SYNC (M, N) and the
    measured end pose (x m, y m, theta rad) in the frame of the start pose."""

    counts: FloatArray
    measured: tuple[float, float, float]
    name: str = "run"


@dataclass(frozen=True)
class FitResult:
    model: str  # "wheels+radius", "scale+radius" or "scale"
    correction: Correction
    predicted_before: FloatArray  # (K, 3) end poses with the configured values
    predicted_after: FloatArray  # (K, 3) end poses with the fitted values
    residual_before: FloatArray  # (K, 3) predicted - measured (theta wrapped)
    residual_after: FloatArray
    iterations: int
    note: str = ""


MODELS = {
    "wheels+radius": "a scale factor per wheel and the base radius",
    "scale+radius": "one scale factor for all wheels and the base radius",
    "scale": "one scale factor for all wheels (the base radius is kept)",
}


def _unpack(model: str, q: FloatArray, n: int) -> Correction:
    if model == "wheels+radius":
        return Correction(tuple(float(v) for v in q[:n]), float(q[n]))
    if model == "scale+radius":
        return Correction.common(n, float(q[0]), float(q[1]))
    return Correction.common(n, float(q[0]))


def _n_params(model: str, n: int) -> int:
    return {"wheels+radius": n + 1, "scale+radius": 2, "scale": 1}[model]


def end_poses(runs: Sequence[FitRun], cfg: ChassisConfig, c: Correction) -> FloatArray:
    """(K, 3) end poses the odometry gives for each run with the correction applied."""
    kin = scaled_kinematics(cfg.kinematics(), c.radius_factor)
    cpm = np.array([w.position_scale * s for w, s in zip(cfg.wheels, c.wheel_factors,
                                                        strict=True)])
    return np.array([integrate(r.counts / cpm, kin)[-1] if len(r.counts) else np.zeros(3)
                     for r in runs])


def _residuals(pred: FloatArray, measured: FloatArray) -> FloatArray:
    res = pred - measured
    res[:, 2] = [wrap_angle(float(v)) for v in res[:, 2]]
    return res


def fit(runs: Sequence[FitRun], cfg: ChassisConfig, model: str = "auto",
        max_iterations: int = 50) -> FitResult:
    """Fit the correction to the runs' measured end poses.

    ``model="auto"`` takes the richest model the data determines: per-wheel scales and
    the radius when there are enough equations (3 per run) and the runs excite every
    parameter, else one common scale and the radius, else the common scale alone.
    Heading residuals count as arc length at the wheels (times the base radius)."""
    if not runs:
        raise ValueError("no recordings to fit")
    n = len(cfg.wheels)
    measured = np.array([r.measured for r in runs], dtype=np.float64)
    if not np.all(np.isfinite(measured)):
        raise ValueError("measured poses must be finite")
    weight = np.array([1.0, 1.0, float(np.mean(cfg.kinematics().base_radius))])

    def residual(model_: str, q: FloatArray) -> FloatArray:
        c = _unpack(model_, q, n)
        out: FloatArray = (_residuals(end_poses(runs, cfg, c), measured) * weight).ravel()
        return out

    def jacobian(model_: str, q: FloatArray) -> FloatArray:
        cols = []
        for k in range(q.size):
            h = 1e-6 * max(1.0, abs(q[k]))
            up, down = q.copy(), q.copy()
            up[k] += h
            down[k] -= h
            cols.append((residual(model_, up) - residual(model_, down)) / (2 * h))
        return np.column_stack(cols)

    candidates = list(MODELS) if model == "auto" else [model]
    if model != "auto" and model not in MODELS:
        raise ValueError(f"unknown model {model!r} (known: {', '.join(MODELS)})")
    note = ""
    chosen = None
    for m in candidates:
        k = _n_params(m, n)
        if 3 * len(runs) < k:
            continue
        q0 = np.ones(k)
        sv = np.linalg.svd(jacobian(m, q0), compute_uv=False)
        if sv.size and sv[-1] > 1e-3 * sv[0] and sv[0] > 0:
            chosen = m
            break
        if model == "auto":
            note = f"the recordings do not determine {MODELS[m]}; "
    if chosen is None:
        raise ValueError("the recordings do not determine any scale: drive an open path "
                         "(e.g. a straight line, then a spin) and give its measured end pose")
    q = np.ones(_n_params(chosen, n))
    r = residual(chosen, q)
    cost = float(r @ r)
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        step = np.linalg.lstsq(jacobian(chosen, q), -r, rcond=None)[0]
        lam, improved = 1.0, False
        while lam > 1e-4 and not improved:
            cand = q + lam * step
            if np.all(cand > 0):
                r_new = residual(chosen, cand)
                improved = float(r_new @ r_new) <= cost
            if not improved:
                lam /= 2
        if not improved:
            break
        q, r = cand, r_new
        new_cost = float(r @ r)
        converged = float(np.max(np.abs(lam * step))) < 1e-12 or cost - new_cost < 1e-18
        cost = new_cost
        if converged:
            break
    correction = _unpack(chosen, q, n)
    before = end_poses(runs, cfg, Correction.common(n, 1.0))
    after = end_poses(runs, cfg, correction)
    return FitResult(chosen, correction, before, after, _residuals(before, measured),
                     _residuals(after, measured), iterations,
                     note + f"fitted {MODELS[chosen]}")
