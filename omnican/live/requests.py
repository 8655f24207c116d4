"""What Foxglove clients send, read with care (:mod:`omnican.live.control` acts on it):
a Twist message in JSON or CDR, a parameter's value, a service request's JSON. Every
message is measured before it is read (:data:`TWIST_LIMIT`, :data:`REQUEST_LIMIT`), a
value quoted back is cut short (:func:`omnican.errors.quote`), JSON's non-numbers and
JSON nested too deeply are refused as any other junk is. Pure: no I/O.
"""

from __future__ import annotations

import json
import math
from typing import Any

from omnican.core.kinematics import Twist
from omnican.errors import quote

TWIST_TYPES = {"geometry_msgs/Twist": False, "geometry_msgs/msg/Twist": False,
               "geometry_msgs/TwistStamped": True, "geometry_msgs/msg/TwistStamped": True}
#: The largest Twist message read (a TwistStamped in JSON with a long frame id is a few
#: hundred bytes), and the largest service request (a console command, a pose).
TWIST_LIMIT = REQUEST_LIMIT = 4096
#: The longest parameter value read as text ("inf", "0.25").
PARAMETER_TEXT_LIMIT = 64


def number(value: Any, where: str) -> float:
    """``value`` as a finite float; ValueError naming ``where`` if it is not one."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where} must be a number, got {quote(value)}")
    if not math.isfinite(value):
        raise ValueError(f"{where} must be finite, got {quote(value)}")
    return float(value)


def _reject_constant(word: str) -> Any:
    raise ValueError(f"not a finite number: {word}")


def check_size(data: bytes, limit: int, what: str) -> None:
    """ValueError if ``data`` is longer than ``limit`` bytes: not read at all."""
    if len(data) > limit:
        raise ValueError(f"{what} of {len(data)} bytes (at most {limit}): not read")


def read_json(data: bytes) -> Any:
    """JSON as the protocol defines it: NaN and Infinity (which Python's json reads) are
    not numbers there. Nesting deeper than Python's recursion allows is refused."""
    try:
        return json.loads(bytes(data), parse_constant=_reject_constant)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"not JSON: {quote(str(exc), 80)}") from None
    except RecursionError:
        raise ValueError("not JSON this program reads: nested too deeply") from None


def decode_twist(encoding: str, schema_name: str, data: bytes) -> Twist:
    """The body twist (vx, vy, wz) of a ``geometry_msgs`` Twist or TwistStamped message
    in ``encoding`` (json or cdr). ValueError saying why it cannot be used: another type,
    another encoding, a field missing or not a finite number."""
    stamped = TWIST_TYPES.get(schema_name)
    if stamped is None:
        raise ValueError("want geometry_msgs/Twist, got "
                         f"{quote(schema_name) if schema_name else 'no schema name'}")
    check_size(data, TWIST_LIMIT, "a message")
    typename = "geometry_msgs/msg/TwistStamped" if stamped else "geometry_msgs/msg/Twist"
    if encoding == "json":
        msg = read_json(data)
    elif encoding == "cdr":
        from omnican.telemetry import cdr

        try:
            msg = cdr.decode(typename, bytes(data))
        except Exception as exc:  # rosbags says little of a short or damaged buffer
            raise ValueError(f"not a CDR {typename}: {type(exc).__name__}") from None
    else:
        raise ValueError(f"cannot read {quote(encoding)} messages (json or cdr)")
    if stamped:
        msg = msg.get("twist") if isinstance(msg, dict) else None
    if not isinstance(msg, dict):
        raise ValueError("want an object with linear and angular")
    parts = []
    for group, axis in (("linear", "x"), ("linear", "y"), ("angular", "z")):
        vector = msg.get(group, {})
        if not isinstance(vector, dict):
            raise ValueError(f"{group} must be an object, got {quote(vector)}")
        parts.append(number(vector.get(axis, 0.0), f"{group}.{axis}"))
    return Twist(*parts)


def parameter_value(name: str, value: Any) -> float | int:
    """A parameter's new value as a limit: a number as it came, or "inf" (also numbers
    as text: the Parameters panel edits a text value as text). ValueError if neither."""
    if isinstance(value, str):
        if len(value) > PARAMETER_TEXT_LIMIT:
            raise ValueError(f"{name}: must be a number, got {quote(value)}")
        text = value.strip().lower()
        try:
            number = math.inf if text in ("inf", "infinity") else float(text)
        except ValueError:
            raise ValueError(f"{name}: must be a number, got {quote(value)}") from None
        if math.isnan(number):
            raise ValueError(f"{name}: must be a number, got {quote(value)}")
        return number
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name}: must be a number, got {quote(value)}")
    return value
