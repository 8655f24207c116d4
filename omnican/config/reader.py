"""One TOML table checked against its :data:`~omnican.config.schema.SCHEMA` section:
its keys known, given where required, of their types, numbers within their ranges. The
first problem is a :class:`ConfigError` naming the file and the key, e.g.
``robot.toml: chassis.rate_hz: must be 1-5000, got 0``.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from omnican.config.schema import SCHEMA, Key
from omnican.errors import ConfigError
from omnican.protocol.cia402 import Mode


def suggest(word: str, known: Iterable[str]) -> str:
    """" (did you mean 'x'?)" for the closest known key; else where the keys are listed
    (a list of every key makes a line no one reads)."""
    close = difflib.get_close_matches(word, list(known), n=1, cutoff=0.75)
    return f" (did you mean {close[0]!r}?)" if close else \
        " (the keys: omnican check-config --help)"


def short(value: Any) -> str:
    """``repr(value)``, at most 40 characters of it (how a message quotes a bad value)."""
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:37]}..."


def whole_path(value: str | None, base_dir: Path | None) -> str | None:
    """A path a config gives (None: none), made whole against the config file's folder
    ``base_dir`` (None: as given); ``~`` expanded."""
    if value is None:
        return None
    p = Path(value).expanduser()
    return str(p if p.is_absolute() or base_dir is None else base_dir / p)


class Reader:
    """Checks one TOML table against its schema, collecting nothing: first error raises.
    ``origin`` (the file) begins every message."""

    def __init__(self, origin: str) -> None:
        self.origin = origin

    def fail(self, where: str, message: str) -> ConfigError:
        return ConfigError(f"{self.origin}: {where}: {message}")

    def table(self, section: str, data: Any, where: str) -> dict[str, Any]:
        if not isinstance(data, dict):
            raise self.fail(where, f"must be a table, got {type(data).__name__}")
        schema = SCHEMA[section]
        for key in data:
            if key not in schema:
                raise self.fail(f"{where}.{key}", f"unknown key {key!r}{suggest(key, schema)}")
        out: dict[str, Any] = {}
        for key, spec in schema.items():
            if key not in data:
                if spec.required:
                    raise self.fail(f"{where}.{key}", "missing required key")
                out[key] = spec.default
                continue
            value = data[key]
            if isinstance(value, bool) and bool not in spec.types:
                raise self.fail(f"{where}.{key}", f"must be a number, got {value!r}")
            if not isinstance(value, spec.types):
                kind = " or ".join(t.__name__ for t in spec.types)
                raise self.fail(f"{where}.{key}", f"must be {kind}, got {value!r}")
            if isinstance(value, float) and math.isnan(value):
                raise self.fail(f"{where}.{key}", "must be a number, got nan")
            self.in_range(f"{where}.{key}", spec, value)
            out[key] = value
        return out

    def in_range(self, where: str, spec: Key, value: Any) -> None:
        """A number within its key's :attr:`Key.range` (inf where the key allows it)."""
        problem = spec.out_of_range(value)
        if problem is not None:
            raise self.fail(where, problem)

    def positive(self, where: str, value: Any, allow_inf: bool = False) -> float:
        v = float(value)
        if not (v > 0) or (math.isinf(v) and not allow_inf):
            raise self.fail(where, f"must be a positive number, got {value!r}")
        return v

    def mode(self, where: str, value: str | None) -> Mode | None:
        """A mode's name (None: not given) as the :class:`Mode` it names."""
        if value is None:
            return None
        try:
            return Mode.from_name(value)
        except ValueError as exc:
            raise self.fail(where, str(exc)) from None
