"""What a new user trips over, tried from a fresh clone: one section per finding of the
sweep of the commands (numbered as in the issue that lists them). Where the behaviour is
the terminal's, the command runs in a pseudo-terminal or a subprocess."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from omnican.cli import main
from omnican.sim import SimulatedBase
from omnican.telemetry.attach import simulator_feed
from tests.support.helpers import one_error_line
from tests.support.terminal import Pty

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
EXAMPLE = EXAMPLES / "robot.toml"
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def run_main(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse: --help, usage errors
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def config_file(tmp_path: Path, extra: str = "", name: str = "robot.toml") -> Path:
    path = tmp_path / name
    path.write_text(EXAMPLE.read_text() + extra)
    return path


# ---------------------------------------------------------------- 1: calibrate's report


OLD_NEW = re.compile(r"(wheel_radius|base_radius|velocity_scale|position_scale) (\S+) -> "
                     r"([0-9.e+-]+)")


def _file_numbers(path: Path) -> dict[str, set[float]]:
    out: dict[str, set[float]] = {}
    for key, value in re.findall(r"^(\w+) = ([0-9.e+-]+)", path.read_text(), re.MULTILINE):
        out.setdefault(key, set()).add(float(value))
    return out


def _check_report(out: str, before: dict[str, set[float]], after: dict[str, set[float]]) -> None:
    printed = OLD_NEW.findall(out)
    assert {k for k, _, _ in printed} == {"wheel_radius", "base_radius"}, out
    for key, old, new in printed:
        assert float(old) in before[key], (key, old, before[key])  # the number it replaced
        assert float(new) in after[key], (key, new, after[key])  # the number it wrote


def test_calibrate_in_place_prints_the_numbers_as_written(tmp_path: Path) -> None:
    cfg = config_file(tmp_path)
    before = _file_numbers(cfg)
    code, out, err = run_main(["calibrate", "--sim", "--fast", "--config", str(cfg), "--write",
                               str(cfg), "--measured-distance", "0.97", "--measured-turns",
                               "1.95"])
    assert code == 0, err
    _check_report(out, before, _file_numbers(cfg))
    assert "wheel_radius 0.05 -> " in out and "base_radius 0.19 -> " in out


def test_calibrate_fit_in_place_prints_the_numbers_as_written(tmp_path: Path) -> None:
    cfg = config_file(tmp_path)
    log = tmp_path / "run.log"
    code, _, err = run_main(["drive", "--sim", "--fast", "--config", str(cfg), "--vx", "0.3",
                             "--wz", "0.5", "--duration", "2", "--record", str(log)])
    assert code == 0, err
    before = _file_numbers(cfg)
    code, out, err = run_main(["calibrate", "--config", str(cfg), "--fit", str(log),
                               "--pose=0.57,0.27,1.03", "--write", str(cfg)])
    assert code == 0, err
    _check_report(out, before, _file_numbers(cfg))


# ---------------------------------------------------------------- 2: check-config, every table


@pytest.mark.parametrize(("extra", "message"), [
    ("\n[gamepad]\ndeadzon = 0.1\n",
     "gamepad.deadzon: unknown key 'deadzon' (did you mean 'deadzone'?)"),
    ("\n[gamepad]\ndeadzone = 1.5\n", "gamepad.deadzone: must be 0 or more and below 1"),
    ("\n[gamepad]\naxis_vx = \"ABS_NOPE\"\n", "gamepad.axis_vx: unknown code 'ABS_NOPE'"),
    ("\n[ros2]\ndomain_id = 999\n", "ros2.domain_id: must be 0-232, got 999"),
    ("\n[ros2]\nodom_frame = \"/odom\"\n", "ros2.odom_frame: must be a tf2 frame id"),
])
def test_check_config_refuses_what_the_commands_refuse(tmp_path: Path, extra: str,
                                                       message: str) -> None:
    cfg = config_file(tmp_path, extra)
    code, out, err = run_main(["check-config", str(cfg)])
    assert code == 2 and "OK" not in out
    assert one_error_line(err).startswith(f"omnican: error: {cfg}: {message}")
    # ... and so does a command that runs the base: nothing moves.
    code, out, err = run_main(["drive", "--sim", "--config", str(cfg), "--vx", "0.1"])
    assert code == 2 and out == ""
    assert message in one_error_line(err)


def test_the_ros2_command_refuses_the_same_line(tmp_path: Path) -> None:
    pytest.importorskip("cyclonedds")
    cfg = config_file(tmp_path, "\n[ros2]\ndomain_id = 999\n")
    _, _, checked = run_main(["check-config", str(cfg)])
    code, _, err = run_main(["ros2", "--sim", "--config", str(cfg), "--duration", "0.1"])
    assert code == 2 and one_error_line(err) == one_error_line(checked)


def test_gamepad_keys_are_in_check_config_help_and_the_reference() -> None:
    """Every [gamepad] key is in check-config --help and in the rows the configuration
    reference (docs/reference/config.md) is generated from."""
    from omnican.command.gamepad import TABLE_KEYS
    from omnican.config import reference_rows

    code, out, _ = run_main(["check-config", "--help"])
    assert code == 0
    documented = {key for key, _, _ in reference_rows()}
    for key in TABLE_KEYS:
        assert f"gamepad.{key}" in out, key
        assert f"gamepad.{key}" in documented, key


# ---------------------------------------------------------------- 3: several configs


def test_check_config_takes_several_files_a_result_each(tmp_path: Path) -> None:
    good = config_file(tmp_path, name="good.toml")
    bad = config_file(tmp_path, "\n[gamepad]\ndeadzon = 0.1\n", name="bad.toml")
    code, out, err = run_main(["check-config", str(good), str(EXAMPLE)])
    assert code == 0, err
    assert f"{good}: OK" in out and f"{EXAMPLE}: OK" in out
    code, out, err = run_main(["check-config", str(bad), str(good)])
    assert code == 2
    assert f"{good}: OK" in out  # the good one is still checked and said so
    assert one_error_line(err).startswith(f"omnican: error: {bad}: gamepad.deadzon")


# ---------------------------------------------------------------- 4: plot --sim-speed


def test_plot_demo_in_simulated_time_at_a_speed(tmp_path: Path) -> None:
    png = tmp_path / "demo.png"
    code, out, err = run_main(["plot", "--sim", "--sim-speed", "4", "--square", "0.2",
                               "--sides", "1", "-o", str(png)])
    assert code == 0, err
    assert png.stat().st_size > 10_000 and out.startswith(f"wrote {png}")


# ---------------------------------------------------------------- 5: scan fits the terminal


@pytest.mark.parametrize("columns", [80, 120])
def test_scan_fits_the_terminal(columns: int) -> None:
    term = Pty("scan", "--sim", "--listen", "0.2", columns=columns)
    try:
        assert term.exit_code(30) == 0
        lines = term.read(0.2).replace("\r", "").splitlines()
    finally:
        term.close()
    assert "3 node(s) found; 0 configured node(s) missing" in lines
    assert max(len(line) for line in lines) <= columns, "\n".join(lines)
    for node in (1, 2, 3):  # a node's row: its id, NMT, device type and check on one line
        assert any(re.match(rf"│ {node} +│ no heartbeat +│ 0x00020192 .*│ ok +│$", line)
                   for line in lines), "\n".join(lines)


# ---------------------------------------------------------------- 6: SIGTERM, early Ctrl-C


def _drive_in_a_terminal(*args: str) -> Pty:
    term = Pty("drive", "--sim", "--vx", "0.1", "--duration", "100", *args)
    term.wait_for("%", timeout=30)  # the progress bar: the base is up and driving
    return term


@pytest.mark.parametrize("json_out", [False, True])
def test_sigterm_stops_the_base_and_says_where(json_out: bool) -> None:
    term = _drive_in_a_terminal(*(["--json"] if json_out else []))
    try:
        time.sleep(0.5)
        term.proc.send_signal(signal.SIGTERM)  # what timeout(1) and systemd send
        assert term.exit_code() == 143
        screen = term.read(0.3)
    finally:
        term.close()
    assert "Traceback" not in screen
    assert "omnican: terminated: the base stopped here" in screen
    if json_out:
        found = re.search(r'^\{"error": "terminated".*\}', screen, re.MULTILINE)
        assert found is not None, screen
        result = json.loads(found[0])
        assert result["pose"]["x"] > 0.02 and "true_pose" in result
    else:
        pose = re.search(r"^pose x=(\S+) y=\S+ theta=\S+", screen, re.MULTILINE)
        assert pose is not None and float(pose[1]) > 0.02, screen


@pytest.mark.parametrize("json_out", [False, True])
def test_ctrl_c_during_bring_up_says_so(served: tuple[SimulatedBase, Path],
                                        json_out: bool) -> None:
    sim, toml = served
    for drive in sim.drives:  # powered but silent: the bring-up waits for their boot-up
        drive.freeze()
    proc = subprocess.Popen(
        [sys.executable, "-m", "omnican", "-v", "drive", "--config", str(toml), "--vx", "0.1",
         *(["--json"] if json_out else [])],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        assert proc.stderr is not None
        seen = []
        for line in proc.stderr:  # the bus is open: the drives are being brought up
            seen.append(line)
            if "bus open" in line:
                break
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    err = "".join(seen) + err
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert "omnican: interrupted during bring-up: nothing moved" in err
    if json_out:
        assert json.loads(out) == {"error": "interrupted", "pose": None, "twist": None,
                                   "wheels": None, "duration_s": None}
    else:
        assert out == ""


HOOK = """
import sys, runpy
class CtrlC:  # a Ctrl-C that lands while {module} is being imported
    def find_spec(self, name, path=None, target=None):
        if name == {module!r}:
            raise KeyboardInterrupt
        return None
sys.meta_path.insert(0, CtrlC())
sys.argv = ["omnican", "drive", "--sim", "--vx", "0.1"]
runpy.run_module("omnican", run_name="__main__")
"""


@pytest.mark.parametrize("module", ["numpy", "can", "canopen"])
def test_ctrl_c_while_starting_up_is_one_line(module: str) -> None:
    proc = subprocess.run([sys.executable, "-c", HOOK.format(module=module)],
                          capture_output=True, text=True, env=ENV, timeout=60, check=False)
    assert proc.returncode == 130, proc.stderr
    assert one_error_line(proc.stderr) == "omnican: interrupted"
    assert proc.stdout == ""


# ---------------------------------------------------------------- 7 and 8: teleop's screen


@pytest.fixture
def sim_port() -> Iterator[int]:
    from tests.process.test_faults_process import SimProcess

    yield free_port()
    while SimProcess.started:
        SimProcess.started.pop().kill()


def test_teleop_says_the_bus_is_back_and_r_recovers(sim_port: int) -> None:
    from tests.process.test_faults_process import SimProcess

    sim = SimProcess(sim_port)
    term = Pty("teleop", "-i", "remote", "-c", f"ws://127.0.0.1:{sim_port}/")
    try:
        term.wait_for_frame("RUNNING", timeout=30)
        sim.kill()
        frame = term.wait_for_frame("STOPPED: CAN bus down")
        assert any("BUS DOWN" in line for line in frame)
        sim = SimProcess(sim_port)
        frame = term.wait_for_frame("the CAN bus is back up - press r to recover", timeout=20)
        status = [line for line in frame if line.startswith("STOPPED")]
        assert len(status) == 1 and "CAN bus down" not in status[0], "\n".join(frame)
        assert not any("BUS DOWN" in line for line in frame), "\n".join(frame)
        term.keys("r")
        term.wait_for_frame("RUNNING", timeout=20)
        term.keys("\x1b")
        assert term.exit_code() == 0
    finally:
        term.close()
        sim.kill()


def test_teleop_wheel_reads_online_when_its_heartbeat_is_back(sim_port: int) -> None:
    from tests.process.test_faults_process import SimProcess

    sim = SimProcess(sim_port)
    term = Pty("teleop", "-i", "remote", "-c", f"ws://127.0.0.1:{sim_port}/")
    try:
        term.wait_for_frame("RUNNING", timeout=30)
        sim.command("heartbeat 1 off")
        term.wait_for_frame("OFFLINE")
        sim.command("heartbeat 1 on")
        end = time.monotonic() + 5.0
        frame = term.frame()
        while time.monotonic() < end and any("OFFLINE" in line for line in frame):
            term.read(0.1)
            frame = term.frame()
        assert not any("OFFLINE" in line for line in frame), "\n".join(frame)
        assert any("press r to recover" in line for line in frame)  # still latched
        term.keys("\x1b")
        assert term.exit_code() == 0
    finally:
        term.close()
        sim.kill()


def test_teleop_at_80x24_keeps_the_newest_events_in_view(
        served: tuple[SimulatedBase, Path]) -> None:
    sim, toml = served
    # The point is the layout: a stall of either process (beside busy ones) must not
    # cost the drives the host's heartbeat first (seen once at the default 0.35 s).
    toml.write_text(toml.read_text().replace('layout = "b21"',
                                             'layout = "b21"\nheartbeat_timeout_factor = 10.0'))
    term = Pty("teleop", "--config", str(toml), columns=80, lines=24)
    try:
        term.wait_for_frame("RUNNING", timeout=30)
        sim.drives[0].inject_fault(0x2310)
        frame = term.wait_for_frame("STOPPED: node 1 fault")
        term.read(1.0)  # the events of the fault have all come in
        frame = term.frame()
        term.keys("\x1b")
        assert term.exit_code() == 0
    finally:
        term.close()
    text = "\n".join(frame)
    assert len(frame) <= 24 and max(len(line) for line in frame) <= 80, text
    # Each wheel on one line of the table (no state or fault text wrapped onto more).
    for wheel, state in ((0, "FAULT"), (1, "OPERATION ENABLED"), (2, "OPERATION ENABLED")):
        assert any(re.match(rf"│ +{wheel} +{wheel + 1} +{state} +[+-]", line) for line in frame), text
    assert "0x2310 continuous over-current" in text  # the fault text is on the screen
    events = frame[next(i for i, line in enumerate(frame) if "events" in line):]
    assert any("base stopped: node 1 fault" in line for line in events), text  # the newest


def _events_of(frame: list[str]) -> list[str]:
    at = next((i for i, line in enumerate(frame) if "─ events ─" in line), None)
    assert at is not None, "no events panel on the screen:\n" + "\n".join(frame)
    return frame[at:]


def test_teleop_at_80x24_keeps_events_in_view_through_stops_and_drops_a_stale_refusal(
        served: tuple[SimulatedBase, Path]) -> None:
    """Issue 31 items 6 and 12: a low battery, r (refused), a fault and the e-stop at
    80x24. The status wrapped onto three lines with the old "recover failed" beside the
    newer stop and the events went off screen; the header did not say which bus, and the
    e-stop's release spoke of recover() rather than the key."""
    sim, toml = served
    toml.write_text(toml.read_text().replace('layout = "b21"',
                                             'layout = "b21"\nheartbeat_timeout_factor = 10.0')
                    + "[power]\nwarn_v = 22.0\ncutoff_v = 20.0\n\n[estop]\nbit = 16\n")
    term = Pty("teleop", "--config", str(toml), columns=80, lines=24)
    try:
        frame = term.wait_for_frame("RUNNING", timeout=30)
        url = toml.read_text().split('channel = "')[1].split('"')[0]
        assert f"base on remote {url}" in frame[0], "\n".join(frame)
        sim.set_battery(19.0)
        term.wait_for_frame("STOPPED: battery low", timeout=20)
        term.keys("r")
        frame = term.wait_for_frame("recover refused")
        assert not any("recover failed: recover" in line for line in frame), "\n".join(frame)
        sim.drives[1].inject_fault(0x2310)
        sim.estop(True)
        frame = term.wait_for_frame("STOPPED: e-stop pressed")
        term.read(1.0)  # the events of the e-stop have all come in
        frame = term.frame()
        text = "\n".join(frame)
        assert len(frame) <= 24 and max(len(line) for line in frame) <= 80, text
        assert "recover refused" not in text, text  # it spoke of the battery stop
        status = [i for i, line in enumerate(frame) if line.startswith("STOPPED")]
        assert len(status) == 1 and "press r" in " ".join(frame[status[0]:status[0] + 2]), text
        assert any("e-stop" in line for line in _events_of(frame)), text  # the newest
        sim.estop(False)
        frame = term.wait_for_frame("e-stop released")
        assert any("e-stop released: press r to start the base again" in line
                   for line in _events_of(frame)), "\n".join(frame)
        assert "recover()" not in "\n".join(frame)
        term.keys("\x1b")
        assert term.exit_code() == 0
    finally:
        term.close()


# ---------------------------------------------------------------- 9: --record formats


def test_record_refuses_a_format_it_cannot_read_back(tmp_path: Path) -> None:
    target = tmp_path / "x.txt"
    code, out, err = run_main(["drive", "--sim", "--vx", "0.1", "--record", str(target)])
    assert code == 2 and out == ""
    line = one_error_line(err)
    assert f"cannot record to {target}" in line and ".log (candump)" in line
    assert not target.exists()


def test_every_format_record_takes_is_read_back(tmp_path: Path) -> None:
    from omnican import default_config
    from omnican.cli.session import recording_suffixes
    from omnican.record import replay

    for suffix in [*recording_suffixes(), ".log.gz"]:
        path = tmp_path / f"run{suffix}"
        code, _, err = run_main(["drive", "--sim", "--fast", "--vx", "0.2", "--duration", "0.3",
                                 "--record", str(path)])
        assert code == 0, (suffix, err)
        rep = replay.load(path, default_config())
        assert rep.complete_syncs > 10 and rep.poses[-1][0] > 0.03, suffix


# ---------------------------------------------------------------- 10: optional extras


def test_the_command_list_marks_every_command_whose_extra_is_missing(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from omnican.extras import install_hint

    monkeypatch.setitem(sys.modules, "cyclonedds", None)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    code, out, _ = run_main(["--help"])
    assert code == 0
    flat = " ".join(out.split())
    for command, module, extra in (("ros2", "cyclonedds", "ros2"),
                                   ("plot", "matplotlib", "plot")):
        assert f"(unavailable: needs {module}: {install_hint(extra)})" in flat, out
        lines = out.splitlines()
        at = next(i for i, line in enumerate(lines) if line.strip().startswith(f"{command} "))
        assert f"(unavailable: needs {module}" in " ".join(lines[at:at + 2]), out


def test_help_of_a_command_whose_extra_is_missing_is_shown(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.delitem(sys.modules, "omnican.cli.plot", raising=False)
    code, out, err = run_main(["plot", "--help"])
    assert code == 0, err
    assert "-o OUT.png, --output OUT.png" in out and "--sim" in out


def test_install_hints_follow_how_omnican_was_installed(monkeypatch: pytest.MonkeyPatch,
                                                        tmp_path: Path) -> None:
    from omnican import extras

    monkeypatch.setattr(extras, "_source", lambda: None)  # from PyPI
    assert extras.install_hint("plot") == "pip install 'omnican[plot]'"
    monkeypatch.setattr(extras, "_source", lambda: (str(ROOT), True))  # a clone, -e
    monkeypatch.chdir(ROOT)
    assert extras.install_hint("plot") == "pip install -e '.[plot]'"  # as README says
    monkeypatch.setattr(extras, "_source", lambda: (str(ROOT), False))  # pip install .
    monkeypatch.chdir(tmp_path)
    assert extras.install_hint("mcap") == f"pip install '{ROOT}[mcap]'"


def test_this_clone_is_told_to_install_from_itself(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    monkeypatch.setitem(sys.modules, "cyclonedds", None)
    code, _, err = run_main(["ros2", "--sim"])
    assert code == 2
    assert one_error_line(err).endswith("'ros2' needs cyclonedds: pip install -e '.[ros2]'")


# ---------------------------------------------------------------- 11: -v anywhere


@pytest.mark.parametrize("argv", [
    ["drive", "--sim", "--vx", "0.1", "--duration", "0.2", "-v"],
    ["-v", "drive", "--sim", "--vx", "0.1", "--duration", "0.2"],
])
def test_verbose_before_or_after_the_command(argv: list[str]) -> None:
    code, _, err = run_main(argv)
    assert code == 0, err
    assert "omnican: INFO: " in err


def test_verbose_counts_on_both_sides() -> None:
    code, _, err = run_main(["-v", "drive", "--sim", "--vx", "0.1", "--duration", "0.2", "-v"])
    assert code == 0 and "omnican: DEBUG: " in err


# ---------------------------------------------------------------- 12: a viewer leaving


def test_a_foxglove_viewer_closing_its_tab_is_no_error() -> None:
    pytest.importorskip("foxglove")
    from tests.support.foxglove_client import FoxgloveClient

    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "omnican", "drive", "--sim", "--vx", "0.05", "--duration", "4",
         "--foxglove", f"127.0.0.1:{port}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        for reset in (True, False):  # a tab killed (RST), a connection cut (no handshake)
            client = FoxgloveClient(f"ws://127.0.0.1:{port}", timeout=30.0)
            client.wait_for_topics(["/odom"])
            client.subscribe(["/odom"])
            time.sleep(0.3)
            sock = client.ws.socket
            if reset:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            else:
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()
            with contextlib.suppress(Exception):  # ends the client's threads
                client.close()
            time.sleep(0.3)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert "ERROR" not in err and "error" not in err, err
    assert out.splitlines()[-1].startswith("pose x=")


# ---------------------------------------------------------------- 13: bus arguments


@pytest.mark.parametrize(("argv", "message"), [
    (["-i", "kvaser"], "the kvaser interface needs a channel: give -c CHANNEL"),
    (["-c", "can0"], "no CAN interface: give -i INTERFACE"),
])
def test_a_bus_that_cannot_be_built_is_a_usage_error(argv: list[str], message: str,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    for var in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("HOME", "/nonexistent")  # no ~/.canrc
    for command in (["drive", "--vx", "0.1"], ["scan"], ["monitor", "--duration", "0.1"],
                    ["sim", "--duration", "0.1"]):
        code, out, err = run_main([*command, *argv])
        assert code == 2 and out == "", (command, err)
        assert message in one_error_line(err), (command, err)


# ---------------------------------------------------------------- 14: help text


def _subparsers() -> dict[str, object]:
    import argparse

    from omnican.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def test_every_option_has_help() -> None:
    import argparse

    for name, parser in _subparsers().items():
        assert isinstance(parser, argparse.ArgumentParser)
        for action in parser._actions:
            if action.option_strings and action.help is not argparse.SUPPRESS:
                assert action.help, (name, action.option_strings)


def test_drive_help_gives_units() -> None:
    code, out, _ = run_main(["drive", "--help"])
    assert code == 0
    for option in ("--vx M/S", "--vy M/S", "--wz RAD/S", "--speed M/S", "--omega RAD/S",
                   "--heading-deg DEG", "--square SIDE", "--duration S"):
        assert option in out, option
    flat = " ".join(out.split())
    assert "speed along the sides, default 0.3" in flat and "default 1)" in flat


def test_monitor_description_and_dbc_help_agree_on_the_default() -> None:
    code, out, _ = run_main(["monitor", "--help"])
    assert code == 0
    flat = " ".join(out.split())
    assert "default: built from --config, else the bundled omnican.dbc" in flat  # --dbc
    assert "default: one built from --config for that robot's drives, else the bundled " \
           "omnican.dbc" in flat  # the description


# ---------------------------------------------------------------- 15: teleop speed beyond limits


def test_teleop_warns_of_a_speed_beyond_the_limits() -> None:
    term = Pty("teleop", "--sim", "--speed", "100", "--turn", "50")
    try:
        frame = term.wait_for_frame("RUNNING", timeout=30)
        text = "\n".join(frame)
        assert "speed 1.00 m/s" in text
        assert "warning: --speed 100 m/s is beyond the base's limits" in text  # events
        term.keys("\x1b")
        assert term.exit_code() == 0
        screen = term.read(0.3)
    finally:
        term.close()
    # On the terminal too, where it stays after the dashboard is gone.
    flat = " ".join(screen.split())
    assert ("omnican: warning: --speed 100 m/s is beyond the base's limits (it reaches 1.00 "
            "m/s: chassis.max_speed, max_wheel_speed): starting at 1.00 m/s") in flat
    assert "omnican: warning: --turn 50 rad/s is beyond the base's limits" in flat


def test_teleop_within_the_limits_warns_nothing() -> None:
    term = Pty("teleop", "--sim", "--speed", "0.5")
    try:
        term.wait_for_frame("RUNNING", timeout=30)
        term.keys("\x1b")
        assert term.exit_code() == 0
        assert "warning" not in term.read(0.3)
    finally:
        term.close()


# ---------------------------------------------------------------- 16: drive's last twist


def test_square_reports_the_twist_once_stopped() -> None:
    code, out, _ = run_main(["drive", "--sim", "--fast", "--square", "0.2", "--speed", "0.4",
                             "--omega", "2"])
    assert code == 0
    assert "measured twist once stopped on the goal: vx=0.000 vy=0.000 wz=0.000" in out, out


def test_timed_motion_reports_the_twist_before_the_stop() -> None:
    code, out, _ = run_main(["drive", "--sim", "--fast", "--vx", "0.3", "--duration", "1"])
    assert code == 0
    assert re.search(r"measured twist before the stop: vx=0\.(29|30|31)\d", out), out


# ---------------------------------------------------------------- 17: calibrate --sim


def test_calibrate_sim_says_what_it_wrote_and_rounds(tmp_path: Path) -> None:
    code, out, _ = run_main(["calibrate", "--sim", "--fast"])
    assert code == 0
    assert out.splitlines()[-1] == ("nothing written: add --write OUT.toml to save the "
                                    "corrected config (OUT may be the --config file)")
    assert "base_radius 0.19 -> 0.1938 m (+2.00 %)" in out  # not 0.1937999
    written = tmp_path / "demo.toml"
    code, out, _ = run_main(["calibrate", "--sim", "--fast", "--write", str(written)])
    assert code == 0
    assert out.splitlines()[-1] == f"wrote the corrected config to {written}"
    assert "base_radius = 0.1938\n" in written.read_text()


def test_hand_measurements_give_what_a_tape_resolves(tmp_path: Path) -> None:
    cfg = config_file(tmp_path)
    code, out, _ = run_main(["calibrate", "--sim", "--fast", "--config", str(cfg),
                             "--measured-distance", "0.974", "--measured-turns", "1.95"])
    assert code == 0
    # 1 mm over 1 m and a degree over two turns: four significant digits.
    wheel = re.search(r"wheel_radius 0\.05 -> (\S+)", out)
    radius = re.search(r"base_radius 0\.19 -> (\S+) m", out)
    assert wheel is not None and radius is not None, out
    assert len(wheel[1].lstrip("0.")) <= 4 and len(radius[1].lstrip("0.")) <= 4, out


# ---------------------------------------------------------------- 18: the plot


@pytest.fixture(scope="module")
def square_replay(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    from omnican import default_config
    from omnican.record import replay
    log = tmp_path_factory.mktemp("plot") / "square.log"
    code, _, err = run_main(["drive", "--sim", "--fast", "--square", "0.3", "--speed", "0.4",
                             "--omega", "2", "--record", str(log)])
    assert code == 0, err
    return replay.load(log, default_config())


def test_plot_of_a_closed_path_shows_start_end_and_what_the_marks_mean(square_replay) -> None:  # type: ignore[no-untyped-def]
    from omnican.cli.plot import build_figure

    truth = [(float(x), float(y)) for x, y, _ in square_replay.poses]
    ax = build_figure(square_replay, "square", truth).get_axes()[0]
    lines = {line.get_label(): line for line in ax.get_lines()}
    start, end = lines["start"], lines["end"]
    assert abs(start.get_xdata()[0] - end.get_xdata()[0]) < 0.01  # closed: they coincide
    # The start is drawn over the end and larger, so that both show.
    assert start.get_zorder() > end.get_zorder()
    assert start.get_markersize() > end.get_markersize() and start.get_markerfacecolor() == "none"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "ground truth end" in labels and "heading at the start" in labels
    assert "heading at the end" in labels


def test_plot_state_chart_ends_in_the_state_the_summary_names(square_replay) -> None:  # type: ignore[no-untyped-def]
    from matplotlib.colors import to_hex

    from omnican.cli.plot import STATE_COLOURS, build_figure, summary
    from omnican.protocol.cia402 import State

    assert "last states: node 1 SWITCH ON DISABLED" in summary(square_replay)
    states = build_figure(square_replay, "square").get_axes()[-1]
    right = states.get_xlim()[1]
    bars = []  # (row, left, right, colour) of every drawn span
    for collection in states.collections:
        for path, colour in zip(collection.get_paths(), collection.get_facecolors(), strict=False):
            xs, ys = path.vertices[:, 0], path.vertices[:, 1]
            bars.append((round(float(ys.mean())), float(xs.min()), float(xs.max()),
                         to_hex(colour)))
    for row in range(len(square_replay.stages)):
        last = max((b for b in bars if b[0] == row), key=lambda b: b[2])
        assert last[3] == STATE_COLOURS[State.SWITCH_ON_DISABLED]
        assert last[2] - last[1] >= 0.01 * right  # wide enough to see


# ---------------------------------------------------------------- 19: startup


HEAVY = ("numpy", "can", "canopen", "cantools", "rich", "matplotlib", "cyclonedds", "foxglove",
         "mcap", "rosbags")
LOADED = """
import sys
from omnican.cli import main
try:
    main({argv!r})
except SystemExit:
    pass
print(" ".join(sorted({{m.split(".")[0] for m in sys.modules}} & set({heavy!r}))))
"""


@pytest.mark.parametrize(("argv", "allowed"), [
    (["--help"], set()),
    (["--version"], set()),
    (["check-config", "--help"], {"numpy"}),
    (["drive", "--help"], {"numpy", "can", "canopen", "rich"}),
    (["plot", "--help"], {"numpy", "can", "canopen", "rich"}),
])
def test_startup_loads_only_what_the_command_needs(argv: list[str], allowed: set[str]) -> None:
    proc = subprocess.run([sys.executable, "-c", LOADED.format(argv=argv, heavy=HEAVY)],
                          capture_output=True, text=True, env=ENV, timeout=60, check=True)
    loaded = set(proc.stdout.split("\n")[-2].split())
    assert loaded <= allowed, (argv, loaded - allowed)


# The process's own command (main() reads sys.argv, as the omnican script does), asked
# when it is done (an exit handler: the process ends in main()) what BLAS threads it ran
# with and whether its heap was frozen.
OWN = """
import atexit, gc, os, sys
sys.argv[1:] = {argv!r}
atexit.register(lambda: print(os.environ.get("OPENBLAS_NUM_THREADS"),
                              gc.get_freeze_count() > 0, gc.isenabled(), flush=True))
from omnican.cli import main
main()
"""
THREADS = OWN.format(argv=["drive", "--sim", "--fast", "--vx", "0.1", "--duration", "0.2",
                           "--json"])


def test_the_command_starts_no_blas_threads() -> None:
    """The ``omnican`` process runs numpy's OpenBLAS on one thread: its worker threads
    (one per core, started as numpy is imported) spun a while at start-up, 30-40 ms of
    CPU of ``drive --sim --fast``, for 3x3 maths. A user's own setting stands."""
    env = {k: v for k, v in ENV.items() if k != "OPENBLAS_NUM_THREADS"}
    for given, seen in ((None, "1"), ("2", "2")):
        run_env = env if given is None else {**env, "OPENBLAS_NUM_THREADS": given}
        proc = subprocess.run([sys.executable, "-c", THREADS], capture_output=True, text=True,
                              env=run_env, timeout=60, check=True)
        assert proc.stdout.split("\n")[-2].split()[0] == seen, (given, proc.stdout[-200:])


def test_the_command_imports_out_of_the_collectors_way() -> None:
    """The command's modules are imported with the collector off and frozen out of its
    reach (gc.freeze): collections do not walk what lives as long as the process; the
    collector is on again for the command itself. A program that calls main(argv) keeps
    its heap as it was."""
    proc = subprocess.run([sys.executable, "-c", OWN.format(argv=["drive", "--help"])],
                          capture_output=True, text=True, env=ENV, timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split("\n")[-2].split()[1:] == ["True", "True"]
    called = ("import gc\nfrom omnican.cli import main\ntry:\n    main(['drive', '--help'])\n"
              "finally:\n    print(gc.get_freeze_count())\n")
    proc = subprocess.run([sys.executable, "-c", called], capture_output=True, text=True,
                          env=ENV, timeout=60, check=False)
    assert proc.stdout.split("\n")[-2] == "0", proc.stderr


# ---------------------------------------------------------------- 20: --record on ros2, monitor


def test_monitor_records_what_it_hears(tmp_path: Path) -> None:
    from omnican import default_config
    from omnican.record import replay
    log = tmp_path / "monitor.log"
    code, _, err = run_main(["monitor", "--sim", "--duration", "1.5", "--record", str(log)])
    assert code == 0, err
    rep = replay.load(log, default_config())
    assert rep.complete_syncs > 20 and rep.poses[-1][0] > 0.01  # the demo circle, recorded


def test_ros2_records_the_bus(tmp_path: Path) -> None:
    pytest.importorskip("cyclonedds")
    from omnican import default_config
    from omnican.record import replay
    log = tmp_path / "ros2.log"
    proc = subprocess.run(
        [sys.executable, "-m", "omnican", "ros2", "--sim", "--localhost", "--domain-id", "95",
         "--duration", "1.5", "--record", str(log)],
        capture_output=True, text=True, env=ENV, timeout=60, check=False, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr
    rep = replay.load(log, default_config())
    assert rep.complete_syncs > 20 and all(len(s.changes) for s in rep.stages)


# ---------------------------------------------------------------- 21: the first power-on


def test_every_example_config_checks_out_with_its_scales() -> None:
    examples = sorted(EXAMPLES.glob("*.toml"))
    code, out, err = run_main(["check-config", *map(str, examples)])
    assert code == 0, err
    for path in examples:
        assert f"{path}: OK" in out
    blocks = out.split(": OK\n")[1:]
    for block in blocks:  # each wheel's scales and the target of a 0.05 m/s jog
        wheels = re.findall(r"^  wheel \d+ \(node \d+.*velocity_scale \S+ per m/s, "
                            r"position_scale \S+ per m.*; 0\.05 m/s = target -?\d+$",
                            block, re.MULTILINE)
        assert len(wheels) == 3, block


def test_the_vendor_drives_of_the_tests_are_shipped_with_a_config_each() -> None:
    from tests.support.helpers import VENDOR_EDS

    assert VENDOR_EDS.parent == EXAMPLES
    texts = [p.read_text() for p in EXAMPLES.glob("*.toml")]
    for eds in VENDOR_EDS.glob("*.eds"):
        assert any(f'eds = "{VENDOR_EDS.name}/{eds.name}"' in t for t in texts), eds.name


def test_the_docs_have_a_first_power_on_checklist() -> None:
    page = (ROOT / "docs" / "bring-up.md").read_text()
    section = page.split("## First power-on checklist", 1)[1].split("\n## ", 1)[0]
    for step in ("off the ground", "omnican check-config", "omnican scan", "--vx 0.05",
                 "Ctrl-C", "wheel", "0.05 m/s = target"):
        assert step in section, step



# ---------------------------------------------------------------- issue 31 item 20


def _driving_client(port: int, sim) -> subprocess.Popen[str]:  # type: ignore[no-untyped-def]
    """``omnican drive`` in a process of its own, on ``sim``'s hub, once the base moves."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "omnican", "drive", "-i", "remote", "-c",
         f"ws://127.0.0.1:{port}/", "--vx", "0.1", "--duration", "120"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    start, end = sim.true_x(), time.monotonic() + 60
    while sim.true_x() <= start + 0.005 and proc.poll() is None and time.monotonic() < end:
        time.sleep(0.2)
    assert proc.poll() is None, proc.communicate()
    return proc


def test_sim_ends_a_killed_client_quietly(sim_port: int) -> None:
    """kill -9 of a client made `omnican sim` print 52 lines and three chained tracebacks."""
    from tests.process.test_faults_process import SimProcess

    sim = SimProcess(sim_port)
    client = _driving_client(sim_port, sim)
    client.kill()
    client.communicate(timeout=10)
    time.sleep(1.0)  # the hub notices the reset connection
    assert sim.command("pose").startswith("true pose")  # the simulator runs on
    _, err = sim.proc.communicate("quit\n", timeout=30)
    sim.proc.stdout = sim.proc.stderr = sim.proc.stdin = None
    assert "Traceback" not in err and "Error" not in err, err
    assert err.strip() == "", err


def test_drive_says_a_stop_once_and_that_the_simulator_went_away(sim_port: int) -> None:
    """drive printed each stop reason twice (a warning and the error); after the simulator
    was SIGTERMed it blamed node 1's heartbeat rather than the bus that went away."""
    from tests.process.test_faults_process import SimProcess

    sim = SimProcess(sim_port)
    client = _driving_client(sim_port, sim)
    sim.command("fault 2")
    _, err = client.communicate(timeout=60)
    assert client.returncode == 1, err
    said = [line for line in err.splitlines() if "base stopped: node 2 fault" in line]
    assert len(said) == 1 and said[0].startswith("omnican: error:"), err

    client = _driving_client(sim_port, sim)  # a new run recovers the drives
    sim.proc.terminate()
    _, err = client.communicate(timeout=60)
    assert client.returncode == 1, err
    assert "base stopped: CAN bus down" in err and "heartbeat lost" not in err, err
    assert len([line for line in err.splitlines() if "base stopped" in line]) == 1, err


# ---------------------------------------------------------------- issue 31 item 11


def test_sim_telemetry_queues_frames_only_while_a_front_end_watches(channel: str) -> None:
    """`omnican sim --foxglove` with no app attached queued every frame its drives heard,
    and on quit said "telemetry dropped ... frames (a front end fell behind)"."""
    import threading

    import can

    from omnican.telemetry.messages import CAN_RX
    from tests.support.helpers import sim_config

    class Probe(can.Listener):  # the notifier calls its listeners in turn, this one last
        def __init__(self) -> None:
            self.seen = 0
            self.got = threading.Event()

        def on_message_received(self, msg: can.Message) -> None:
            if msg.arbitration_id == 0x5AA:
                self.seen += 1
                if self.seen % 20 == 0:
                    self.got.set()

    class Watcher:
        def __init__(self) -> None:
            self.frames = threading.Event()

        def wants(self, topic: str) -> bool:
            return True

        def publish(self, messages: list) -> None:  # type: ignore[type-arg]
            if any(msg.topic == CAN_RX for msg in messages):
                self.frames.set()

    cfg = sim_config(channel)
    probe = Probe()
    with SimulatedBase.from_config(cfg) as sim, simulator_feed(sim) as feed, \
            can.Bus(interface="virtual", channel=channel) as other:
        assert sim.network.notifier is not None
        sim.network.notifier.add_listener(probe)
        for _ in range(20):
            other.send(can.Message(arbitration_id=0x5AA, data=b"\x01", is_extended_id=False))
        assert probe.got.wait(10)
        assert not [f for f in feed.frames.queue if f[1] == 0x5AA]  # no one to take them
        watcher = Watcher()
        feed.add(watcher)
        probe.got.clear()
        for _ in range(20):
            other.send(can.Message(arbitration_id=0x5AA, data=b"\x02", is_extended_id=False))
        assert probe.got.wait(10)
        assert watcher.frames.wait(10)  # a front end still gets the frames
        feed.remove(watcher)
        sim.network.notifier.remove_listener(probe)
    assert feed.frames.dropped == 0


@pytest.mark.parametrize("speed", ["1e9", "-21", "20.5"])
def test_the_console_refuses_a_push_no_wheel_reaches(channel: str, speed: str) -> None:
    """`push 1 1e9` was accepted, and the dashboard then showed theta 193551 rad."""
    from omnican.sim.console import command
    from tests.support.helpers import sim_config

    with SimulatedBase.from_config(sim_config(channel)) as sim:
        reply = command(sim, f"push 1 {speed}") or ""
        assert reply.startswith("error: push takes -20 to 20 m/s at the rim"), reply
        assert sim.drives[0].axes[0].pushed_counts_s is None
        assert command(sim, "push 1 -20") == "node 1: pushed at -20 m/s"


def test_sim_console_prompts_a_person_at_a_terminal() -> None:
    term = Pty("sim", "--serve", "127.0.0.1:0")
    try:
        term.wait_for("type a command here")
        term.read(0.5)
        assert term.read(0.1).rstrip("\r\n").endswith("> "), term.read(0.1)[-300:]
        term.keys("pose\n")
        term.wait_for("true pose")
        term.read(0.3)
        assert term.read(0.1).endswith("true pose x=0.0000 y=0.0000 theta=0.0000\r\n> ")
        term.keys("quit\n")
        assert term.exit_code(timeout=30) == 0
    finally:
        term.close()


def test_ros2_help_lists_every_console_command_and_battery_state() -> None:
    from omnican.sim.console import COMMANDS

    code, out, _ = run_main(["ros2", "--help"])
    assert code == 0
    for syntax, _ in COMMANDS:
        assert syntax in out, (syntax, out)
    assert "recover" in out and "battery_state" in out
