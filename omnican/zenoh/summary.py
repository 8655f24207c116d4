"""The fleet's view of one base: the ``<ns>/base_summary`` message (JSON text in a
``std_msgs/msg/String``), what a fleet view lists a base by.

Pure: the bridge hands :class:`Summarizer` the JSON data of one sample's ``/status``,
``/wheels``, ``/pose2d`` and ``/twist`` (the one telemetry model's, so the summary says
what every other front end says at that moment) and who drives the base; it answers a
summary when one is due: once a period of the sample's clock, and at once when the
state, the stop reason, the e-stop or the set of drive faults changes (a fleet view hears
a stop within a sample, not within a period). :func:`parse` reads one back, checking
every field: a summary comes from the network, and a malformed one must not take a fleet
view down. Each number must be finite (JSON has no NaN; a view's own ``--json`` must stay
JSON), and each text is cut and shown printable (:func:`omnican.errors.printable`: a
peer's text cannot steer the terminal it is shown on).

The fields (docs/fleet.md): ``node``, ``state`` (RUNNING, STOPPED, STARTING),
``stopped_reason``, ``enabled``, ``estop``, ``pose`` {x, y, theta}, ``speed`` {vx, vy, wz}
(measured), ``battery_v`` (absent when unmeasured), ``faults`` (one line per faulted
wheel), ``driver`` (absent when no one drives), ``stamp`` (s), ``period_s``, and
``true_speed`` only when the simulator's truth goes along.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from omnican.errors import printable

#: What a summary is made from: the JSON topics of one sample.
SOURCES = ("/status", "/wheels", "/pose2d", "/twist")
#: A base whose summary is older than this many of its periods is silent.
SILENT_PERIODS = 3
MAX_TEXT = 200  # characters kept of a text field read from the network
MAX_FAULTS = 16
#: The largest summary read (its CDR bytes); a base's is under 1 KiB, with sixteen long
#: faults under 4 KiB.
MAX_BYTES = 16 * 1024

Vector = tuple[float, float, float]


def faults(wheels: Mapping[str, Any]) -> list[str]:
    """One line per wheel whose drive reports a fault or an error: ``wheel 2: ...``."""
    out = []
    for w in wheels.get("wheels", ()):
        trouble = w.get("fault") or w.get("error")
        if trouble:
            out.append(f"wheel {w['index']}: {trouble}")
    return out


def _speed(t: Mapping[str, Any]) -> dict[str, float]:
    return {"vx": t["vx"], "vy": t["vy"], "wz": t["wz"]}


def compose(data: Mapping[str, Mapping[str, Any]], stamp_ns: int, *, node: str,
            driver: str | None, period_s: float) -> dict[str, Any]:
    """The summary of one sample: ``data`` maps each of :data:`SOURCES` to its message's
    data; ``node`` is the base's fully qualified node name."""
    status, twist, pose = data["/status"], data["/twist"], data["/pose2d"]
    out: dict[str, Any] = {
        "node": node, "state": status["state"], "stopped_reason": status["stopped_reason"],
        "enabled": status["enabled"], "estop": status["estop"],
        "pose": {"x": pose["x"], "y": pose["y"], "theta": pose["theta"]},
        "speed": _speed(twist["measured"]), "faults": faults(data["/wheels"]),
        "stamp": stamp_ns / 1e9, "period_s": period_s}
    if status.get("battery_v") is not None:
        out["battery_v"] = status["battery_v"]
    if driver is not None:
        out["driver"] = driver
    if "true" in twist:
        out["true_speed"] = _speed(twist["true"])
    return out


def signature(summary: Mapping[str, Any]) -> tuple[Any, ...]:
    """What a change of goes out at once."""
    return (summary["state"], summary["stopped_reason"], summary["estop"],
            tuple(summary["faults"]))


class Summarizer:
    """When a base's summary is due (see the module docstring). ``period_s``: the
    summary's period, in the base's clock (the samples' stamps)."""

    def __init__(self, node: str, period_s: float) -> None:
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"a summary period is a positive number of seconds, "
                             f"not {period_s!r}")
        self.node = node
        self.period_s = period_s
        self._period_ns = round(period_s * 1e9)
        self._last_ns: int | None = None
        self._signature: tuple[Any, ...] | None = None

    def offer(self, data: Mapping[str, Mapping[str, Any]], stamp_ns: int,
              driver: str | None) -> dict[str, Any] | None:
        """The summary of this sample if one is due, else None (also when ``data``
        lacks one of :data:`SOURCES`: a sample without the base's state)."""
        if any(topic not in data for topic in SOURCES):
            return None
        summary = compose(data, stamp_ns, node=self.node, driver=driver,
                          period_s=self.period_s)
        sig = signature(summary)
        if (self._last_ns is not None and sig == self._signature
                and 0 <= stamp_ns - self._last_ns < self._period_ns):
            return None
        self._last_ns, self._signature = stamp_ns, sig
        return summary


# ------------------------------------------------------------------ reading one back


@dataclass(frozen=True)
class Summary:
    """A base's summary as a fleet view reads it (see the module docstring)."""

    node: str
    state: str
    stopped_reason: str
    enabled: bool
    estop: bool
    pose: Vector  # x m, y m, theta rad
    speed: Vector  # vx m/s, vy m/s, wz rad/s (measured)
    faults: tuple[str, ...]
    stamp: float
    period_s: float
    battery_v: float | None = None
    driver: str | None = None
    true_speed: Vector | None = None

    def as_json(self) -> dict[str, Any]:
        """Back to the message's fields (what :func:`compose` wrote)."""
        out: dict[str, Any] = {
            "node": self.node, "state": self.state, "stopped_reason": self.stopped_reason,
            "enabled": self.enabled, "estop": self.estop,
            "pose": dict(zip(("x", "y", "theta"), self.pose, strict=True)),
            "speed": dict(zip(("vx", "vy", "wz"), self.speed, strict=True)),
            "faults": list(self.faults), "stamp": self.stamp, "period_s": self.period_s}
        if self.battery_v is not None:
            out["battery_v"] = self.battery_v
        if self.driver is not None:
            out["driver"] = self.driver
        if self.true_speed is not None:
            out["true_speed"] = dict(zip(("vx", "vy", "wz"), self.true_speed, strict=True))
        return out


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{what} is not a number: {printable(repr(value), 40)}")
    number = float(value)  # an int too large for a float raises OverflowError: caught
    if not math.isfinite(number):
        raise ValueError(f"{what} is not a finite number: {number!r}")
    return number


def _text(value: Any, what: str) -> str:
    if not isinstance(value, str):
        raise ValueError(f"{what} is not text: {printable(repr(value), 40)}")
    return printable(value, MAX_TEXT)


def _flag(value: Any, what: str) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{what} is not true or false: {printable(repr(value), 40)}")
    return value


def _vector(value: Any, names: tuple[str, str, str], what: str) -> Vector:
    if not isinstance(value, dict):
        raise ValueError(f"{what} is not an object: {printable(repr(value), 40)}")
    a, b, c = (_number(value.get(n), f"{what}.{n}") for n in names)
    return a, b, c


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def text_of(cdr: bytes) -> str:
    """The text of a std_msgs/msg/String's CDR (little or big endian, with its header:
    what :func:`omnican.zenoh.bridge.string_cdr` makes); ValueError for bytes that are
    not one, or are longer than :data:`MAX_BYTES`."""
    if len(cdr) > MAX_BYTES:
        raise ValueError(f"{len(cdr)} bytes, more than a summary's {MAX_BYTES}")
    if len(cdr) < 9 or cdr[0] != 0 or cdr[1] not in (0, 1):
        raise ValueError(f"not a CDR String ({len(cdr)} bytes)")
    (size,) = struct.unpack_from("<I" if cdr[1] == 1 else ">I", cdr, 4)
    text = cdr[8:8 + size]
    if size == 0 or len(text) != size or text[-1] != 0:
        raise ValueError(f"not a CDR String (a {size}-byte string in {len(cdr) - 8} bytes)")
    try:
        return text[:-1].decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError("not UTF-8 text") from None


def parse(data: bytes | str) -> Summary:
    """A summary's JSON text read and checked; ValueError saying what is wrong (NaN,
    Infinity and numbers too large for a float included: they are not JSON's)."""
    try:
        d = json.loads(data, parse_constant=_no_constant)
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"not JSON: {printable(str(exc), MAX_TEXT)}") from None
    except RecursionError:
        raise ValueError("not JSON a base writes: nested too deeply") from None
    if not isinstance(d, dict):
        raise ValueError("not a JSON object")
    try:
        return _read(d)
    except OverflowError:
        raise ValueError("a number too large for a float") from None


def _read(d: dict[str, Any]) -> Summary:
    raw_faults = d.get("faults")
    if not isinstance(raw_faults, list):
        raise ValueError(f"faults is not a list: {printable(repr(raw_faults), 40)}")
    period = _number(d.get("period_s"), "period_s")
    if not period > 0:
        raise ValueError(f"period_s is not a positive number: {period!r}")
    battery, driver, true = d.get("battery_v"), d.get("driver"), d.get("true_speed")
    return Summary(
        node=_text(d.get("node"), "node"), state=_text(d.get("state"), "state"),
        stopped_reason=_text(d.get("stopped_reason"), "stopped_reason"),
        enabled=_flag(d.get("enabled"), "enabled"), estop=_flag(d.get("estop"), "estop"),
        pose=_vector(d.get("pose"), ("x", "y", "theta"), "pose"),
        speed=_vector(d.get("speed"), ("vx", "vy", "wz"), "speed"),
        faults=tuple(_text(f, "a fault") for f in raw_faults[:MAX_FAULTS]),
        stamp=_number(d.get("stamp"), "stamp"), period_s=period,
        battery_v=None if battery is None else _number(battery, "battery_v"),
        driver=None if driver is None else _text(driver, "driver"),
        true_speed=None if true is None else _vector(true, ("vx", "vy", "wz"), "true_speed"))
