"""Run a program as if only ``pip install '.[EXTRA]'`` had been done, in the test venv.

The test command installs ``.[test,docs]`` into one venv, so a docs build there could use
pytest, hypothesis or anything else the tests brought without anyone noticing (it did:
the layers picture imported tests/test_layers.py, which imports pytest). Installing a
second venv with only the docs extra would prove it too, at the price of a second install
of Sphinx, matplotlib and numpy in every CI run. Instead the program runs with an import
guard: every installed distribution outside the dependency closure of ``omnican[EXTRA]``
(read from the installed metadata, so it follows pyproject.toml) has its top-level modules
hidden from the import system, as if not installed, in the program and in every Python
program it starts (a ``sitecustomize`` on PYTHONPATH).
"""

from __future__ import annotations

import importlib.metadata as md
import os
import re
import sys
from collections.abc import Iterable
from pathlib import Path

from packaging.requirements import Requirement

#: What a fresh ``python3 -m venv`` has before anything is installed into it.
FRESH_VENV = {"pip"} | ({"setuptools"} if sys.version_info < (3, 12) else set())

ENV = "OMNICAN_TEST_HIDDEN_MODULES"

SITECUSTOMIZE = f'''\
"""Hide the modules named by {ENV} (tests/docs/extra_only.py): every finder of the
import system is wrapped so that it finds none of them, as if they were not installed
(an import fails with ModuleNotFoundError, importlib.util.find_spec gives None)."""
import os
import sys

_HIDDEN = frozenset(filter(None, os.environ.get("{ENV}", "").split(",")))


class _Hiding:
    def __init__(self, inner):
        self._inner = inner

    def find_spec(self, name, path=None, target=None):
        if name.split(".", 1)[0] in _HIDDEN:
            return None
        find = getattr(self._inner, "find_spec", None)
        return None if find is None else find(name, path, target)

    def __getattr__(self, name):
        return getattr(self._inner, name)


sys.meta_path[:] = [_Hiding(finder) for finder in sys.meta_path]
'''


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def closure(root: str, extras: Iterable[str]) -> set[str]:
    """The canonical names of ``root[extras]`` and every distribution it needs, as the
    installed metadata says (markers evaluated for this Python)."""
    seen: set[str] = set()
    todo: list[tuple[str, frozenset[str]]] = [(root, frozenset(extras))]
    done: set[tuple[str, frozenset[str]]] = set()
    while todo:
        name, wanted = todo.pop()
        if (_canonical(name), wanted) in done:
            continue
        done.add((_canonical(name), wanted))
        try:
            dist = md.distribution(name)
        except md.PackageNotFoundError:
            continue  # not installed here (a marker for another platform, say)
        seen.add(_canonical(name))
        for line in dist.requires or []:
            req = Requirement(line)
            envs = [{"extra": e} for e in wanted] or [{"extra": ""}]
            if req.marker is not None and not any(req.marker.evaluate(e) for e in envs):
                continue
            todo.append((req.name, frozenset(req.extras)))
    return seen


def hidden_modules(root: str, extras: Iterable[str]) -> set[str]:
    """The top-level modules installed here that ``pip install root[extras]`` would not
    bring (a module that an allowed distribution also provides is allowed)."""
    allowed = closure(root, extras) | FRESH_VENV
    hidden: set[str] = set()
    for module, dists in md.packages_distributions().items():
        if not any(_canonical(d) in allowed for d in dists):
            hidden.add(module)
    return hidden


def guarded_env(tmp: Path, root: str, extras: Iterable[str],
                base: dict[str, str] | None = None) -> dict[str, str]:
    """An environment whose Python programs can import only what ``root[extras]``
    installs (and the standard library); ``tmp`` receives the sitecustomize."""
    (tmp / "sitecustomize.py").write_text(SITECUSTOMIZE)
    env = dict(os.environ if base is None else base)
    env[ENV] = ",".join(sorted(hidden_modules(root, extras)))
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(tmp), env.get("PYTHONPATH")]))
    return env
