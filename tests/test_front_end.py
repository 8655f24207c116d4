"""A newcomer adds a front end by writing one folder and one registry line (issue 39):
the echo front end (``tests/support/echo_front_end.py``), registered at run time, is
offered by the commands, its table is read and checked by the config, and it runs
beside a simulated base: it takes the base's telemetry and stops the base."""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from pathlib import Path

import pytest

from omnican import Chassis
from omnican.cli import build_parser, front_ends, main
from omnican.config import load_config, reference_rows
from omnican.core.kinematics import Twist
from omnican.errors import ConfigError
from omnican.front_end import FrontEnd, plugin, registered
from omnican.layers import FRONT_ENDS, FrontEndEntry
from omnican.sim import SimulatedBase
from tests.support.echo_front_end import EchoFrontEnd, EchoTable
from tests.support.helpers import sim_config, wait_for

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "robot.toml"
ENTRY = FrontEndEntry("tests.support.echo_front_end:EchoFrontEnd")


@pytest.fixture
def echo() -> Iterator[None]:
    with registered("echo", ENTRY):
        yield


def run_main(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


def config(tmp_path: Path, table: str) -> Path:
    path = tmp_path / "robot.toml"
    path.write_text(EXAMPLE.read_text() + table)
    return path


def test_every_registered_front_end_is_a_plug_in_of_its_own_folder() -> None:
    for name, entry in FRONT_ENDS.items():
        cls = plugin(name)
        assert issubclass(cls, FrontEnd) and cls.name == name
        assert cls.__module__.startswith(f"omnican.{entry.folder}.")


def test_its_table_is_read_and_checked_through_the_registry(echo: None,
                                                            tmp_path: Path) -> None:
    cfg = load_config(config(tmp_path, "\n[echo]\nstop_after = 5\n"))
    assert cfg.front_ends["echo"] == EchoTable(stop_after=5)
    assert ("echo.stop_after", "-", "stop the base after this many /odom messages") in \
        reference_rows()
    with pytest.raises(ConfigError, match=r"robot\.toml: echo\.stop_after: must be "
                                          r"1-1000000, got 0$"):
        load_config(config(tmp_path, "\n[echo]\nstop_after = 0\n"))
    with pytest.raises(ConfigError, match=r"echo\.stop_afte: unknown key 'stop_afte' \(did you mean "
                                          r"'stop_after'\?\)$"):
        load_config(config(tmp_path, "\n[echo]\nstop_afte = 5\n"))


def test_without_its_registry_line_a_config_has_no_such_table(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="unknown section 'echo'"):
        load_config(config(tmp_path, "\n[echo]\nstop_after = 5\n"))


def test_the_commands_offer_it(echo: None) -> None:
    code, out, _ = run_main(["drive", "--help"])
    assert code == 0 and "--echo-stop-after N" in out
    code, out, _ = run_main(["teleop", "--help"])
    assert code == 0 and "--echo-stop-after N" in out
    code, out, _ = run_main(["sim", "--help"])  # it offered nothing beside a simulator alone
    assert code == 0 and "--echo" not in out
    code, _, err = run_main(["drive", "--sim"])
    assert code == 2 and "--echo-stop-after to take it from Foxglove or Zenoh or Echo" in err


def test_it_runs_beside_a_simulated_base_takes_its_telemetry_and_stops_it(
        echo: None, channel: str) -> None:
    cfg = sim_config(channel)
    args = build_parser("drive").parse_args(["drive", "--echo-stop-after", "10"])
    running = front_ends.from_args(args, cfg, "base")
    assert [type(f) for f in running] == [EchoFrontEnd]
    [front_end] = running
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base, \
            front_ends.attached(running, base, sim):
        driver = base.command_source("a driver")
        refused: list[str] = []

        def stopped_by_echo() -> bool:
            who = driver.drive(Twist(0.2, 0.0, 0.0)).refused_by
            if who is not None:
                refused.append(who)
            return who is not None

        assert wait_for(stopped_by_echo, 10.0, 0.02)
        assert front_end.count >= 10 and front_end.stopped
        assert refused == ["echo"] and driver.stopped_by() == "echo"
        assert wait_for(lambda: abs(base.twist.vx) < 1e-3, 10.0)
    assert front_end.headline.startswith("Echo ")


def test_a_command_runs_it_and_it_stops_the_motion(echo: None) -> None:
    code, _, err = run_main(["drive", "--sim", "--vx", "0.1", "--duration", "60",
                             "--echo-stop-after", "10"])
    assert code == 1
    assert "Echo: counting /odom; stop after 10" in err
    assert "omnican: error: base stopped: stopped by echo" in err
