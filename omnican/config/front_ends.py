"""The front ends' tables of a config (``[ros2]``, ``[foxglove]``, ``[zenoh]``...), one
typed table of them: each front end declares its own (a :class:`TableSpec`: its keys,
the frozen dataclass they become, its own checks), and the config reads each through the
front ends' registry (:data:`omnican.layers.FRONT_ENDS`), importing a front end's plug-in
only when its table is read, checked or listed, as python-can finds a backend by name.

A config holds them as :class:`FrontEndTables` (``cfg.front_ends["zenoh"]``): only the
tables the file gave, each a :class:`FrontEndTable`, which reads as a mapping of its keys
too (what the front end's settings are made from).
"""

from __future__ import annotations

import importlib
import sys
import warnings
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omnican.config.schema import Key
from omnican.layers import FRONT_ENDS

if TYPE_CHECKING:
    from omnican.config.reader import Reader


@dataclass(frozen=True)
class FrontEndTable(Mapping[str, Any]):
    """A front end's table, checked: a frozen dataclass whose fields are its keys (and
    ``given``, the keys the file gave, if the table keeps them), read as a mapping of
    its keys too."""

    def _keys(self) -> tuple[str, ...]:
        return tuple(f.name for f in fields(self) if f.name != "given")

    def __getitem__(self, key: str) -> Any:
        if key not in self._keys():
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys())

    def __len__(self) -> int:
        return len(self._keys())


#: What a front end's ``read`` is handed: the reader (its errors name the file and the
#: key), the table's values checked against its keys (each key, its default where not
#: given), the keys the file gave, and the config file's folder (paths are relative to it).
Read = Callable[["Reader", dict[str, Any], frozenset[str], "Path | None"], FrontEndTable]


@dataclass(frozen=True)
class TableSpec:
    """How a front end's table is read: its keys (their types, defaults, ranges and
    meaning: README's reference, ``check-config --help``), and ``read``, its own checks
    of the values, making its :class:`FrontEndTable`. ``telemetry``: keys of it that
    every front end's telemetry reads (frames, joint names, rates: ``[ros2]``'s)."""

    keys: Mapping[str, Key]
    read: Read
    telemetry: tuple[str, ...] = ()


def plugin(name: str) -> Any:
    """The plug-in class of the front end registered as ``name``, imported now."""
    module, _, cls = FRONT_ENDS[name].plugin.partition(":")
    return getattr(importlib.import_module(module), cls)


def table_spec(name: str) -> TableSpec | None:
    """The table the front end ``name`` reads (None: it reads none)."""
    spec: TableSpec | None = plugin(name).table
    return spec


def read_tables(r: Reader, data: Mapping[str, Any], base_dir: Path | None) -> FrontEndTables:
    """The front ends' tables ``data`` (the whole TOML document) gives, each checked
    against its keys and by its front end."""
    tables = {}
    for name in FRONT_ENDS:
        if name not in data:
            continue
        spec = table_spec(name)
        if spec is None:
            raise r.fail(name, f"the {name} front end reads no table")
        values = r.table(name, data[name], name)
        given = frozenset(data[name])
        tables[name] = spec.read(r, values, given, base_dir)
    return FrontEndTables(tables)


def read_table(name: str, data: Mapping[str, Any], origin: str = "config",
               base_dir: Path | None = None) -> FrontEndTable:
    """One front end's table from its values (a TOML table), checked as a config file's."""
    from omnican.config.reader import Reader

    r = Reader(origin)
    tables = read_tables(r, {name: dict(data)}, base_dir)
    return tables[name]


class FrontEndTables(Mapping[str, FrontEndTable]):
    """A config's front-end tables by front end: those the file gave, in the registry's
    order. Frozen; :meth:`replace` makes a copy with one table changed."""

    def __init__(self, tables: Mapping[str, FrontEndTable] | None = None) -> None:
        given = dict(tables or {})
        self._tables = {name: given.pop(name) for name in FRONT_ENDS if name in given}
        self._tables.update(given)  # front ends registered at run time (tests)

    def __getitem__(self, name: str) -> FrontEndTable:
        return self._tables[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._tables)

    def __len__(self) -> int:
        return len(self._tables)

    def __repr__(self) -> str:
        return f"FrontEndTables({self._tables!r})"

    def replace(self, name: str, table: FrontEndTable) -> FrontEndTables:
        """A copy with ``name``'s table ``table``."""
        return FrontEndTables({**self._tables, name: table})

    def telemetry(self) -> dict[str, Any]:
        """What every front end's telemetry reads (frames, joint names, rates...): the
        keys each registered front end's table names for it (:attr:`TableSpec.telemetry`),
        as the table gives them (None: not given), else their defaults."""
        out: dict[str, Any] = {}
        for name in FRONT_ENDS:
            spec = table_spec(name)
            if spec is None or not spec.telemetry:
                continue
            table = self._tables.get(name)
            for key in spec.telemetry:
                value = table.get(key) if table is not None else None
                out[key] = spec.keys[key].default if value is None else value
        return out


def moved(owner: str, name: str, table: Any) -> Any:
    """``owner.<name>``, a front end's table under the name it had before the tables
    were one (``cfg.zenoh``): the table, and a DeprecationWarning naming its new home."""
    warnings.warn(f"{owner}.{name} moved to {owner}.front_ends[{name!r}]; the old name goes "
                  "in the next release", DeprecationWarning, stacklevel=3)
    return table


def moved_name(name: str) -> Any:
    """A name ``omnican.config`` had that moved to a front end's own table module (its
    ``MOVED_FROM_CONFIG``), with a DeprecationWarning naming its new home; AttributeError
    for any other."""
    for front_end in FRONT_ENDS:
        spec = table_spec(front_end)
        module = sys.modules[spec.read.__module__] if spec is not None else None
        if module is not None and name in getattr(module, "MOVED_FROM_CONFIG", ()):
            warnings.warn(f"omnican.config.{name} moved to {module.__name__}.{name}; the old "
                          "name goes in the next release", DeprecationWarning, stacklevel=3)
            return getattr(module, name)
    raise AttributeError(f"module 'omnican.config' has no attribute {name!r}")


