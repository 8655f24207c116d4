"""One configuration key's spec (:class:`Key`): its TOML types, default, range and
meaning. The tables of them are :data:`omnican.config.schema.SCHEMA`'s.

Pure data: no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

#: The TOML types of a number.
NUMBER = (int, float)


@dataclass(frozen=True)
class Key:
    """One configuration key: its TOML type(s), default (None: none, or see ``required``
    and ``scaled``) and meaning. The one place a default is written: the dataclasses the
    tables parse into take theirs from here (:func:`schema_defaults`)."""

    types: tuple[type, ...]
    default: Any
    doc: str
    required: bool = False
    #: (other key, factor): left out, the key is ``factor`` x the other key's value.
    scaled: tuple[str, float] | None = None
    #: (lowest, highest) a number may be, both allowed; None: any finite number. Beyond
    #: it a value has no physical sense for a base (or overflows what it feeds): refused.
    range: tuple[float, float] | None = None
    #: inf is allowed too (no such limit).
    inf_ok: bool = False
    #: ``range`` bounds the magnitude; the sign is free (a polarity), zero is not.
    signed: bool = False
    #: The highest value of ``range`` is not allowed itself (a fraction below 1).
    open_high: bool = False

    def range_text(self) -> str:
        """The range as an error message says it: "0.001-60", "-720 to 720"."""
        if self.range is None:
            return "a finite number"
        lo, hi = (_bound_text(x) for x in self.range)
        text = f"{lo}-{hi}" if self.range[0] >= 0 else f"{lo} to {hi}"
        if self.signed:
            text = f"{lo} to {hi} in magnitude (either sign)"
        if self.open_high:
            text = f"{lo} or more and below {hi}"
        return text + (" or inf" if self.inf_ok else "")

    def out_of_range(self, value: Any) -> str | None:
        """What is wrong with a number beyond :attr:`range` ("must be 0.01-60, got 100"),
        None for one within it (inf where the key allows it) or for no number."""
        if self.range is None or isinstance(value, bool) or not isinstance(value, NUMBER):
            return None
        if math.isinf(value) and self.inf_ok and value > 0:
            return None
        lo, hi = self.range
        v = abs(value) if self.signed else value
        if lo <= v < hi or (v == hi and not self.open_high):
            return None
        shown = f"{value:.6g}" if isinstance(value, float) else str(value)
        return f"must be {self.range_text()}, got {shown}"


def _bound_text(x: float) -> str:
    """A range's bound as people write it: 1000000, not 1e+06; 1e+12 stays."""
    return str(int(x)) if x == int(x) and abs(x) < 1e7 else f"{x:g}"
