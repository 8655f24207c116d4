"""Every code snippet of README.md and docs/*.md runs as pasted, against the simulated base.

- Each ```python block runs in a process of its own, from the repository's root (where
  ``examples/robot.toml`` is), with this tree on PYTHONPATH.
- Each ```sh block runs its ``omnican`` lines in order, in a scratch directory that sees
  the repository's ``examples/``, ``dbc/`` and ``eds/``: those with ``--sim`` (simulated
  drives in the same process), and after one of them the offline ``plot`` and
  ``check-config`` lines that read what it wrote. ``teleop`` (it needs a terminal) and
  ``--foxglove-control`` (it waits for a Foxglove client to drive it) are not run;
  neither is a line that needs a bus of another process. Commands that need hardware,
  root or a terminal are fenced ```console and never run.

A snippet that raises, or a command that exits non-zero or hangs, fails its test.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
TIMEOUT_S = 300  # a loaded 2-core machine runs eight suites at once
#: the DDS domain of the ROS 2 snippets: none of the other tests' (each has its own)
DOCS_DOMAIN = "211"


@dataclass(frozen=True)
class Block:
    page: str  # relative to the repository
    line: int  # of the opening fence, 1-based
    lang: str
    body: str  # dedented to the fence's indentation

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line}"


_FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>`{3,}|~{3,})(?P<info>[^`\n]*)$")


def fenced_blocks(text: str, page: str) -> list[Block]:
    """The fenced code blocks of a Markdown page (CommonMark fences, indented ones in
    lists included), with their language."""
    blocks: list[Block] = []
    lines = text.split("\n")
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        indent, fence = m["indent"], m["fence"]
        lang = m["info"].strip().split(" ")[0]
        body: list[str] = []
        j = i + 1
        while j < len(lines):
            close = lines[j].strip()
            if close.startswith(fence[0] * len(fence)) and set(close) == {fence[0]}:
                break
            line = lines[j]
            body.append(line[len(indent):] if line.startswith(indent) else line.lstrip())
            j += 1
        else:
            raise AssertionError(f"{page}:{i + 1}: a fence that is never closed")
        blocks.append(Block(page, i + 1, lang, "\n".join(body) + "\n"))
        i = j + 1
    return blocks


def all_blocks() -> list[Block]:
    return [b for p in PAGES for b in fenced_blocks(p.read_text(), str(p.relative_to(ROOT)))]


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("CAN_", "CYCLONEDDS"))}
    env["PYTHONPATH"] = str(ROOT)
    return env


def run_python(code: str, name: str, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    script = tmp_path / (re.sub(r"\W", "_", name) + ".py")
    script.write_text(code)
    return subprocess.run([sys.executable, str(script)], cwd=ROOT, env=_env(), text=True,
                          capture_output=True, timeout=TIMEOUT_S, stdin=subprocess.DEVNULL,
                          check=False)


# ---------------------------------------------------------------- shell lines


def commands(body: str) -> list[str]:
    """The block's command lines, continuation lines joined."""
    out: list[str] = []
    pending = ""
    for line in body.splitlines():
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1] + " "
            continue
        out.append(pending + line)
        pending = ""
    return [c for c in out if c.strip()]


def why_not_run(line: str, after_a_run: bool) -> str | None:
    """None when the line runs here; else why it does not."""
    words = shlex.split(line, comments=True)
    if not words or words[0] != "omnican":
        return "not an omnican command"
    sub = words[1] if len(words) > 1 else ""
    if sub == "teleop":
        return "teleop needs a terminal"
    if "--foxglove-control" in words:
        return "waits for a Foxglove client to drive it"
    if "--sim" in words:
        return None
    if after_a_run and sub in ("plot", "check-config"):
        return None  # offline: it reads what the block's run wrote, or the repo's files
    return "needs the bus of another process or hardware"


def runnable(block: Block) -> list[str]:
    lines, ran = [], False
    for line in commands(block.body):
        if why_not_run(line, ran) is None:
            lines.append(line)
            ran = True
    return lines


def loopback_port(line: str) -> str:
    """The line with a Foxglove server on a free loopback port: ``--foxglove`` alone serves
    on 127.0.0.1:8765, a port another test (or the user's Foxglove) may hold."""
    words = shlex.split(line, comments=True)
    if "--foxglove" in words:
        at = words.index("--foxglove")
        if at + 1 == len(words) or words[at + 1].startswith("-"):
            words.insert(at + 1, "127.0.0.1:0")
        return shlex.join(words)
    return line


def run_shell(lines: list[str], tmp_path: Path) -> list[tuple[str, subprocess.CompletedProcess[str]]]:
    """Run ``lines`` in order with bash, ``omnican`` being this tree's, in a scratch
    directory; stops at the first that fails."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    wrapper = bin_dir / "omnican"
    wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m omnican "$@"\n')
    wrapper.chmod(0o755)
    work = tmp_path / "work"
    work.mkdir(exist_ok=True)
    for name in ("examples", "dbc", "eds"):
        if (ROOT / name).exists() and not (work / name).exists():
            (work / name).symlink_to(ROOT / name)
    env = _env()
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    env["ROS_DOMAIN_ID"] = DOCS_DOMAIN
    done = []
    for line in lines:
        proc = subprocess.run(["bash", "-c", loopback_port(line)], cwd=work, env=env, text=True,
                              capture_output=True, timeout=TIMEOUT_S,
                              stdin=subprocess.DEVNULL, check=False)
        done.append((line, proc))
        if proc.returncode != 0:
            break
    return done


# ---------------------------------------------------------------- the tests

PYTHON = [b for b in all_blocks() if b.lang == "python"]
SHELL = [b for b in all_blocks() if b.lang == "sh" and runnable(b)]


def test_the_pages_have_snippets_to_run() -> None:
    assert len(PYTHON) >= 5, [b.id for b in PYTHON]
    assert any(b.page == "README.md" for b in PYTHON)
    assert len(SHELL) >= 5, [b.id for b in SHELL]


@pytest.mark.parametrize("block", PYTHON, ids=[b.id for b in PYTHON])
def test_python_snippet_runs(block: Block, tmp_path: Path) -> None:
    proc = run_python(block.body, block.id, tmp_path)
    assert proc.returncode == 0, f"{block.id}\n{block.body}\n{proc.stdout}\n{proc.stderr}"


@pytest.mark.parametrize("block", SHELL, ids=[b.id for b in SHELL])
def test_shell_snippet_runs(block: Block, tmp_path: Path) -> None:
    lines = runnable(block)
    done = run_shell(lines, tmp_path)
    for line, proc in done:
        assert proc.returncode == 0, f"{block.id}: {line}\n{proc.stdout}\n{proc.stderr}"
    assert len(done) == len(lines)


# ---------------------------------------------------------------- the runner can fail


def test_a_broken_python_snippet_fails(tmp_path: Path) -> None:
    ok = run_python("from omnican import Twist\nprint(Twist(1.0, 0.0, 0.0))\n", "ok", tmp_path)
    assert ok.returncode == 0 and "Twist(vx=1.0" in ok.stdout, ok.stderr
    broken = run_python("from omnican import Chassis, load_config\n"
                        "load_config('robot.toml')\n", "broken", tmp_path)
    assert broken.returncode != 0 and "robot.toml" in broken.stderr


def test_a_broken_shell_line_fails(tmp_path: Path) -> None:
    done = run_shell(["omnican drive --sim --vx fast --duration 0.1",
                      "omnican drive --sim --vx 0.1 --duration 0.1"], tmp_path)
    assert len(done) == 1  # stopped at the first failure
    assert done[0][1].returncode == 2, done[0][1].stderr


def test_which_shell_lines_run() -> None:
    assert why_not_run("omnican drive --sim --fast --square 1  # a comment", False) is None
    assert why_not_run("omnican teleop --sim", False) == "teleop needs a terminal"
    assert why_not_run("omnican ros2 --sim --foxglove-control", False) is not None
    assert why_not_run("omnican sim", False) is not None
    assert why_not_run("omnican plot run.log -o run.png", False) is not None
    assert why_not_run("omnican plot run.log -o run.png", True) is None
    assert why_not_run("pip install '.[mcap]'", True) == "not an omnican command"
    block = fenced_blocks("text\n   ```sh\n   omnican drive --sim \\\n     --vx 0.1\n   ```\n",
                          "x.md")
    assert block == [Block("x.md", 2, "sh", "omnican drive --sim \\\n  --vx 0.1\n")]
    assert [line.split() for line in runnable(block[0])] == [
        ["omnican", "drive", "--sim", "--vx", "0.1"]]
