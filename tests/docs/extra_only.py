"""Run a program as if only ``pip install '.[EXTRA]'`` had been done, in the test venv.

The test command installs ``.[test,docs]`` into one venv, so a docs build there could use
pytest, hypothesis or anything else the tests brought without anyone noticing (it did:
the layers picture imported tests/test_layers.py, which imports pytest). Installing a
second venv with only the docs extra would prove it too, at the price of a second install
of Sphinx, matplotlib and numpy in every CI run. Instead the program runs with an import
guard: every installed distribution outside the dependency closure of ``omnican[EXTRA]``
(read from the installed metadata, so it follows pyproject.toml) has its top-level modules
refused, in the program and in every Python program it starts (a ``sitecustomize`` on
PYTHONPATH).
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

ENV = "OMNICAN_TEST_REFUSE_IMPORTS"

SITECUSTOMIZE = f'''\
"""Refuse the modules named by {ENV} (tests/docs/extra_only.py)."""
import importlib.abc
import os
import sys

_REFUSED = frozenset(filter(None, os.environ.get("{ENV}", "").split(",")))


class _Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".", 1)[0] in _REFUSED:
            raise ModuleNotFoundError(
                f"No module named {{name!r}} (refused: the extra under test does not "
                f"install it)", name=name)
        return None


sys.meta_path.insert(0, _Refuse())
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


def refused_modules(root: str, extras: Iterable[str]) -> set[str]:
    """The top-level modules installed here that ``pip install root[extras]`` would not
    bring (a module that an allowed distribution also provides is allowed)."""
    allowed = closure(root, extras) | FRESH_VENV
    refused: set[str] = set()
    for module, dists in md.packages_distributions().items():
        if not any(_canonical(d) in allowed for d in dists):
            refused.add(module)
    return refused


def guarded_env(tmp: Path, root: str, extras: Iterable[str],
                base: dict[str, str] | None = None) -> dict[str, str]:
    """An environment whose Python programs can import only what ``root[extras]``
    installs (and the standard library); ``tmp`` receives the sitecustomize."""
    (tmp / "sitecustomize.py").write_text(SITECUSTOMIZE)
    env = dict(os.environ if base is None else base)
    env[ENV] = ",".join(sorted(refused_modules(root, extras)))
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(tmp), env.get("PYTHONPATH")]))
    return env
