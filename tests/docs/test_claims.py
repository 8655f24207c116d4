"""What the pages say of the code, checked against the code where that is cheap (issue
36, item 16): the architecture page's threads, the files a change touches and the
modules it names; the first slow jog, one command on every page."""

from __future__ import annotations

import re
import threading

from omnican import Chassis
from omnican.plan.health_fields import HEALTH_FIELDS
from omnican.sim import SimulatedBase
from tests.support.helpers import ROOT, sim_config

ARCHITECTURE = (ROOT / "docs" / "architecture.md").read_text()
PACKAGE = ROOT / "omnican"


def _bullet(title: str) -> str:
    """The text of one "Where a change goes" bullet, ``- **title**...``."""
    start = ARCHITECTURE.index(f"- **{title}**")
    end = ARCHITECTURE.find("\n- **", start + 1)
    return ARCHITECTURE[start:end if end > 0 else None]


def test_every_module_the_architecture_page_names_is_there() -> None:
    named = set(re.findall(r"`((?:[a-z0-9_]+/)*[a-z0-9_]+\.py)`", ARCHITECTURE))
    assert len(named) > 40
    missing = sorted(n for n in named
                     if not (PACKAGE / n).is_file() and not (ROOT / n).is_file())
    assert not missing, missing


def test_a_health_field_names_every_file_that_holds_one() -> None:
    """Each file that names a health field's scale key (``voltage_scale``: the config's
    schema, the wheel's model, the wheels' parsing, the health plan) is named where the
    page says what adding a field touches; so are the table and the simulator's model."""
    bullet = _bullet("A health field")
    assert bullet.startswith("- **A health field** (something each drive reports). Five "
                             "files:"), bullet[:120]
    five = {"plan/health_fields.py", "config/schema.py", "config/model.py",
            "config/wheels.py", "sim/health.py"}
    keys = [f"{f.quantity}_scale" for f in HEALTH_FIELDS]
    holding = {p.relative_to(PACKAGE).as_posix() for p in PACKAGE.rglob("*.py")
               if any(k in p.read_text() for k in keys)}
    assert {"config/schema.py", "config/model.py", "config/wheels.py"} <= holding
    for path in sorted(holding | five):
        assert f"`{path}`" in bullet, path


def test_while_the_base_runs_the_loop_reads_the_bus_not_a_notifier(channel: str) -> None:
    """As the thread table and the TPDO walk say: after start, python-can's Notifier is
    stopped and the loop polls; before and after, a Notifier receives."""
    cfg = sim_config(channel)
    with SimulatedBase.from_config(cfg), Chassis.open(cfg) as base:
        assert base.bus.polling and base.bus.network.notifier is None
        names = {t.name for t in threading.enumerate()}
        assert "omnican-loop" in names
    notifier_row = next(line for line in ARCHITECTURE.splitlines()
                        if line.startswith("| python-can's Notifier |"))
    assert "`start_polling` stops it" in notifier_row and "before the loop starts" in notifier_row
    loop_row = next(line for line in ARCHITECTURE.splitlines()
                    if line.startswith("| `omnican-loop` |"))
    assert "reads the bus once a cycle" in loop_row
    walk = ARCHITECTURE.split("**A TPDO to Foxglove's `/odom`.**", 1)[1].split("\n\n", 1)[0]
    assert "the loop thread reads the bus" in walk and "`CanBus.poll`" in walk
    assert "Notifier thread (owned" not in walk


JOG = re.compile(r"omnican drive --config robot\.toml --vx ([0-9.]+) --duration ([0-9.]+)")


def test_the_first_slow_jog_is_one_command_everywhere() -> None:
    """README's robot section, the bring-up steps and the first power-on checklist give
    the same first motion, and the checklist's expected pose is what it drives."""
    pages = {"README.md": (ROOT / "README.md").read_text(),
             "docs/bring-up.md": (ROOT / "docs" / "bring-up.md").read_text()}
    found = [(page, m.groups()) for page, text in pages.items() for m in JOG.finditer(text)]
    assert len(found) >= 3, found
    assert len({jog for _, jog in found}) == 1, found
    vx, duration = (float(v) for v in found[0][1])
    checklist = pages["docs/bring-up.md"].split("## First power-on checklist", 1)[1]
    checklist = checklist.split("\n## ", 1)[0]
    assert JOG.search(checklist)
    assert f"`x={vx * duration:g}`" in checklist


def test_the_moved_names_are_on_the_architecture_page() -> None:
    from tests.test_moved_names import MOVED

    for old, new in MOVED.items():
        assert f"`omnican.{old}`" in ARCHITECTURE and f"`omnican.{new}`" in ARCHITECTURE
