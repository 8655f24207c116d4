"""The dependency floors in pyproject.toml are honest: exactly those versions install
into a fresh virtual environment, and omnican runs there (import, check-config, a short
simulated drive).

The environment is cached under ~/.cache/omnican/min-versions/, keyed by the Python
and the pinned versions, so only a change of floor pays for the install. Skipped,
with the reason, when the package index cannot be reached.
``OMNICAN_MIN_VERSIONS_PYTHON=/usr/bin/python3.10`` checks the floors of another Python.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.version import Version

from omnican.config import tomllib
from tests.support.helpers import locked

ROOT = Path(__file__).resolve().parents[2]
PIP_TIMEOUT_S = 900
RUN_TIMEOUT_S = 120
# pip's words for "the index did not answer" (as opposed to "no such version").
_OFFLINE = re.compile(r"NewConnectionError|Failed to establish|Temporary failure in name "
                      r"resolution|Network is unreachable|ConnectTimeout|ReadTimeout|"
                      r"Could not fetch URL|ProxyError|SSLError", re.I)


def target_python() -> str:
    return os.environ.get("OMNICAN_MIN_VERSIONS_PYTHON") or sys.executable


def marker_environment(python: str) -> dict[str, str]:
    code = ("import json, platform, sys; print(json.dumps({'python_version': "
            "'%d.%d' % sys.version_info[:2], 'python_full_version': platform.python_version(), "
            "'sys_platform': sys.platform, 'platform_machine': platform.machine(), "
            "'implementation_name': sys.implementation.name}))")
    out = subprocess.run([python, "-c", code], capture_output=True, text=True, check=True)
    env: dict[str, str] = json.loads(out.stdout)
    return env


def floors(python: str) -> list[str]:
    """``name==floor`` for every dependency of pyproject.toml that applies to ``python``."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    env = marker_environment(python)
    pins = []
    for text in project["dependencies"]:
        req = Requirement(text)
        if req.marker is not None and not req.marker.evaluate(env):
            continue
        lows = [s.version for s in req.specifier if s.operator == ">="]
        assert len(lows) == 1, f"{text}: a dependency needs exactly one floor (>=)"
        pins.append(f"{req.name}=={lows[0]}")
    return sorted(pins)


def pip(venv_python: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(venv_python), "-m", "pip", "--disable-pip-version-check", *args],
                          capture_output=True, text=True, timeout=PIP_TIMEOUT_S, check=False)


def fail_or_skip(what: str, result: subprocess.CompletedProcess[str]) -> None:
    output = result.stdout + result.stderr
    tail = "\n".join(output.strip().splitlines()[-15:])
    if _OFFLINE.search(output) and "No matching distribution" not in output:
        pytest.skip(f"package index unreachable ({what}): {tail.splitlines()[-1]}")
    pytest.fail(f"{what} failed:\n{tail}")


@pytest.fixture(scope="module")
def floor_env() -> tuple[Path, list[str]]:
    python = target_python()
    pins = floors(python)
    key = hashlib.sha256("\n".join([*pins, str(marker_environment(python))]).encode())
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    venv = cache / "omnican" / "min-versions" / key.hexdigest()[:16]
    venv_python = venv / "bin" / "python"
    done = venv / "omnican-floors.txt"
    with locked(venv.with_suffix(".lock")):
        if not (done.is_file() and done.read_text().split() == pins and venv_python.exists()):
            shutil.rmtree(venv, ignore_errors=True)
            subprocess.run([python, "-m", "venv", str(venv)], check=True, timeout=120)
            result = pip(venv_python, "install", "--no-input", *pins)
            if result.returncode != 0:
                shutil.rmtree(venv, ignore_errors=True)
                fail_or_skip("installing the floors " + " ".join(pins), result)
            done.write_text("\n".join(pins) + "\n")
    return venv_python, pins


def run(venv_python: Path, *args: str) -> subprocess.CompletedProcess[str]:
    # omnican from this source tree; everything else from the floor environment only.
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["PYTHONPATH"] = str(ROOT)
    return subprocess.run([str(venv_python), *args], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=RUN_TIMEOUT_S, check=False)


def test_the_floors_are_what_got_installed(floor_env: tuple[Path, list[str]]) -> None:
    venv_python, pins = floor_env
    names = [p.split("==")[0] for p in pins]
    code = ("import importlib.metadata as m, json, sys; "
            "print(json.dumps({n: m.version(n) for n in sys.argv[1:]}))")
    out = run(venv_python, "-c", code, *names)
    assert out.returncode == 0, out.stderr
    installed = json.loads(out.stdout)
    for pin in pins:
        name, version = pin.split("==")
        assert Version(installed[name]) == Version(version), pin


def test_omnican_runs_on_its_floors(floor_env: tuple[Path, list[str]]) -> None:
    venv_python, _ = floor_env
    out = run(venv_python, "-c", "import omnican, omnican.cli, omnican.sim, omnican.io.hub; "
              "print(omnican.__file__)")
    assert out.returncode == 0, out.stderr
    assert Path(out.stdout.strip()).is_relative_to(ROOT)  # this tree, not an installed copy
    out = run(venv_python, "-m", "omnican", "check-config", "examples/robot.toml")
    assert out.returncode == 0, out.stderr
    assert "examples/robot.toml: OK" in out.stdout and "bus load at 500 kbit/s" in out.stdout
    out = run(venv_python, "-m", "omnican", "drive", "--sim", "--vx", "0.1", "--duration", "0.5",
              "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["pose"]["x"] > 0.02
    assert result["pose"]["x"] == pytest.approx(result["true_pose"]["x"], abs=0.005)
