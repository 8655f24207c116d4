"""Names that moved keep working for one release, each with a DeprecationWarning naming
its new home: ``omnican.motion``, ``omnican.teleop_model`` and ``omnican.slamware``
(which went with the layers' restructure without one: issue 36, item 16)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from omnican.layers import FACE
from tests.support.helpers import ROOT

MOVED = {"motion": "command.motion", "teleop_model": "command.teleop",
         "slamware": "protocol.slamware"}

PROBE = """
import importlib, json, sys, warnings
old, new, form = sys.argv[1:]
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    import omnican
    quiet = [str(w.message) for w in caught]
    if form == "from":
        module = getattr(__import__("omnican", fromlist=[old]), old)
    else:
        module = importlib.import_module(f"omnican.{old}")
print(json.dumps({"same": module is importlib.import_module(f"omnican.{new}"),
                  "quiet": quiet,
                  "warned": [[w.category.__name__, str(w.message)] for w in caught]}))
"""


@pytest.mark.parametrize("form", ["from", "import"])
@pytest.mark.parametrize("old", sorted(MOVED))
def test_a_moved_name_is_the_new_module_with_a_warning(old: str, form: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", PROBE, old, MOVED[old], form],
                         capture_output=True, text=True, env=env, timeout=60, check=True)
    seen = json.loads(out.stdout)
    assert seen["same"]
    assert seen["quiet"] == []  # import omnican alone warns of nothing
    assert seen["warned"] == [[
        "DeprecationWarning", f"omnican.{old} moved to omnican.{MOVED[old]}; the old name "
        "goes in the next release"]]


def test_the_moved_names_are_the_face_s() -> None:
    assert set(MOVED) == FACE - {"__init__", "__main__"}
