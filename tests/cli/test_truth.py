"""Every command tells the truth: what it prints is what it did (issue 11).

Each test drives the command through ``omnican.cli.main`` (or a subprocess) as a
user would, and reads its output."""

from __future__ import annotations

import contextlib
import io
import json
import math
import re
import sys
from pathlib import Path
from typing import Any

import pytest

from omnican.cli import main
from tests.support.helpers import one_error_line

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "robot.toml"


def run_main(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse errors
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


# ---------------------------------------------------------------- 1: calibrate --write

PHYSICAL = """\
[chassis]
layout = "b21"
base_radius = 0.19
max_accel = 3.0
max_angular_accel = 12.0

[[wheel]]
node_id = 1
gear_ratio = 16
encoder_cpr = 4096
wheel_radius = 0.05     # m

[[wheel]]
node_id = 2
velocity_scale = 208607.6
position_scale = 208607.6

[[wheel]]
node_id = 3
velocity_scale = 208607.6
position_scale = 208607.6
"""


def test_calibrate_prints_what_it_writes_in_the_configs_own_terms(tmp_path: Path) -> None:
    cfg = tmp_path / "robot.toml"
    cfg.write_text(PHYSICAL)
    out_toml = tmp_path / "out.toml"
    code, out, err = run_main(["calibrate", "--sim", "--fast", "--config", str(cfg), "--distance", "0.2",
                               "--turns", "0.25", "--speed", "0.5", "--omega", "3",
                               "--write", str(out_toml)])
    assert code == 0, err
    written = out_toml.read_text()
    # Every "key old -> new" the command prints is a line it wrote, and every number it
    # changed is printed.
    printed = re.findall(r"(\w+) (\S+) -> ([0-9.]+)", out)
    assert printed, out
    before, after = PHYSICAL.splitlines(), written.splitlines()
    assert after[len(before) + 1].startswith("[sim]")  # the simulated base, recorded apart
    changed = [(a.split("=")[0].strip(), a.split("=")[1].split()[0],
                b.split("=")[1].split()[0])
               for a, b in zip(before, after[:len(before)], strict=True)
               if a != b]
    assert sorted((k, float(o), float(n)) for k, o, n in printed) == \
        sorted((k, float(o), float(n)) for k, o, n in changed)
    wheel0 = next(line for line in out.splitlines() if "wheel 0 (node 1)" in line)
    assert "wheel_radius 0.05 -> " in wheel0 and "velocity_scale" not in wheel0


# ---------------------------------------------------------------- 2: a missing extra


@pytest.mark.parametrize("argv", [
    ["plot", "run.log", "-o", "out.png"],
    ["plot", "-o", "out.png"],
    ["-v", "plot", "--sim", "-o", "demo.png"],
])
def test_a_command_whose_extra_is_missing_says_which_to_install(
        argv: list[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib now fails
    monkeypatch.delitem(sys.modules, "omnican.cli.plot", raising=False)
    code, _, err = run_main(argv)
    assert code == 2
    line = one_error_line(err)
    from omnican.extras import install_hint

    assert "'plot' needs matplotlib" in line and install_hint("plot") in line
    assert "unrecognized arguments" not in line


def test_the_command_list_marks_the_unavailable_command(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.delitem(sys.modules, "omnican.cli.plot", raising=False)
    from omnican.extras import install_hint

    code, out, _ = run_main(["--help"])
    assert code == 0
    assert re.search(r"plot\s+.*\s+\(unavailable: needs matplotlib: "
                     + re.escape(install_hint("plot")) + r"\)", out), out


# ---------------------------------------------------------------- 3: one clean line


def test_a_garbage_eds_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "junk.eds").write_text("garbage text\nnot an eds\n")
    cfg = tmp_path / "robot.toml"
    cfg.write_text(EXAMPLE.read_text().replace("node_id = 1\n", 'node_id = 1\neds = "junk.eds"\n',
                                               1))
    for argv in (["check-config", str(cfg)], ["drive", "--sim", "--config", str(cfg), "--vx",
                                               "0.1"]):
        code, _, err = run_main(argv)
        assert code == 2
        line = one_error_line(err)
        assert "junk.eds" in line and "cannot parse EDS" in line, line


def test_no_drive_on_the_bus_is_said_once(channel: str) -> None:
    code, out, err = run_main(["drive", "-i", "virtual", "-c", channel, "--vx", "0.1"])
    assert code == 1
    line = one_error_line(err)
    assert line.startswith("omnican: error: no drive answered on the bus: nodes 1, 2, 3:"), line
    assert line.count("no boot-up") == 1
    assert out == ""


@pytest.mark.parametrize("text", ["hello world\nnot a log\n", "(1.0) can0\n", "\x00\x01\x02"])
def test_a_junk_recording_is_one_line_without_internals(tmp_path: Path, text: str) -> None:
    junk = tmp_path / "junk.log"
    junk.write_text(text)
    for argv in (["plot", str(junk), "-o", str(tmp_path / "out.png")],
                 ["calibrate", "--fit", str(junk), "--pose", "1,0,0"]):
        code, _, err = run_main(argv)
        assert code == 2
        line = one_error_line(err)
        assert line.startswith(f"omnican: error: {junk}: not a readable .log recording"), line
        assert "unpack" not in line and "expected 3" not in line and "index" not in line


def test_the_sim_console_answers_a_bad_number_in_words() -> None:
    from omnican.cli.sim import command

    class Drive:
        node_id = 1

        def inject_fault(self, code: int) -> None:
            raise AssertionError("must not fault on a bad code")

    class Sim:
        def __init__(self) -> None:
            self.drives = [Drive()]

    reply = command(Sim(), "fault 1 0xZZ")  # type: ignore[arg-type]
    assert reply == "error: not an emergency code: '0xZZ' (e.g. 0x2310)"
    assert command(Sim(), "fault x1") == "error: not a node id: 'x1' (nodes: 1)"  # type: ignore[arg-type]


# ---------------------------------------------------------------- 5: the sim console


class _Drive:
    def __init__(self, node_id: int) -> None:
        self.node_id = node_id
        self.calls: list[str] = []

    def __getattr__(self, name: str):  # type: ignore[no-untyped-def]
        return lambda *a: self.calls.append(name)


class _Sim:
    def __init__(self) -> None:
        self.drives = [_Drive(1), _Drive(2)]


@pytest.mark.parametrize(("line", "reply"), [
    ("heartbeat 1 maybe", "error: heartbeat takes on, off or periodic, not 'maybe'"),
    ("heartbeat 1", "error: heartbeat takes a node id and on, off or periodic"),
    ("blah", "error: unknown command 'blah' (try 'help')"),
    ("blah 1", "error: unknown command 'blah' (try 'help')"),
    ("fault", "error: fault needs a node id (nodes: 1, 2)"),
    ("reboot 3", "error: no simulated node 3 (nodes: 1, 2)"),
])
def test_the_sim_console_refuses_what_it_does_not_understand(line: str, reply: str) -> None:
    from omnican.cli.sim import command

    sim = _Sim()
    assert command(sim, line) == reply  # type: ignore[arg-type]
    assert all(d.calls == [] for d in sim.drives)  # nothing was done


def test_the_sim_console_does_what_it_says() -> None:
    from omnican.cli.sim import command

    sim = _Sim()
    assert command(sim, "heartbeat 2 off") == "node 2: heartbeat off"  # type: ignore[arg-type]
    assert command(sim, "HEARTBEAT 2 ON") == "node 2: heartbeat on"  # type: ignore[arg-type]
    assert sim.drives[1].calls == ["stop_heartbeat", "start_heartbeat"]


def test_the_sim_banner_lists_the_commands() -> None:
    import os
    import subprocess

    proc = subprocess.run([sys.executable, "-m", "omnican", "sim", "--serve", "127.0.0.1:0",
                           "--duration", "0.3"], check=False, capture_output=True, text=True,
                          timeout=60, stdin=subprocess.DEVNULL,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr
    for verb in ("fault NODE [CODE]", "reboot NODE", "heartbeat NODE off|on", "freeze NODE",
                 "thaw NODE", "pose", "help", "quit"):
        assert verb in proc.stdout, proc.stdout


# ---------------------------------------------------------------- 4: arguments refused


@pytest.mark.parametrize(("argv", "message"), [
    (["drive", "--square", "1", "--duration", "2"], "--duration is not used with --square"),
    (["drive", "--sim", "--heading-deg", "90"], "--heading-deg needs --speed"),
    (["drive", "--sim", "--vx", "1e308"], "motion refused: vx 1e+308 m/s is beyond any wheeled "
                                          "base (at most 100"),
    (["drive", "--sim", "--speed", "1e200"], "motion refused: vx 1e+200 m/s is beyond"),
    (["drive", "--sim"], "give a motion: --vx/--vy/--wz, --speed/--heading-deg/--omega, "
                         "--square SIDE, or --foxglove-control or --zenoh to take it from "
                         "Foxglove or Zenoh"),
    (["drive", "--sim", "--duration", "2"], "give a motion"),
    (["drive", "--sim", "--foxglove-control", "--vx", "0.1"],
     "--foxglove-control takes the motion from Foxglove: give no motion, only --duration"),
    (["drive", "--sim", "--foxglove-control", "--square", "1"], "takes the motion from Foxglove"),
    (["drive", "--sim", "--fast", "--foxglove-control", "--duration", "1"],
     "--foxglove-control drives in real time: drop --fast and --sim-speed"),
    (["drive", "--sim", "--foxglove-control", "--foxglove", "0.0.0.0:0", "--duration", "1"],
     "--foxglove-control on 0.0.0.0:0 lets anyone who reaches this host drive the robot: add "
     "--foxglove-allow-remote"),
    (["drive", "--sim", "--no-foxglove-control", "--foxglove", "127.0.0.1:0"], "give a motion"),
    (["sim", "--frame-loss", "2", "--duration", "0.1"], "--frame-loss must be 0-1, got 2"),
    (["sim", "--encoder-noise", "inf", "--duration", "0.1"], "--encoder-noise"),
    (["check-config", str(EXAMPLE), "--bitrate", "-5"], "argument --bitrate: must be a "
                                                        "positive whole number, got '-5'"),
    (["check-config", str(EXAMPLE), "--bitrate", "0"], "must be a positive whole number"),
    (["sim", "--serve", "0.0.0.0:5000", "--duration", "0.1"],
     "--serve 0.0.0.0:5000: the hub serves loopback only, and 0.0.0.0 is every interface "
     "(use 127.0.0.1)"),
])
def test_arguments_that_make_no_sense_are_refused(argv: list[str], message: str) -> None:
    code, out, err = run_main(argv)
    assert code == 2
    assert message in one_error_line(err)
    assert out == ""


def test_a_port_in_use_is_a_runtime_failure() -> None:
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code, _, err = run_main(["sim", "--serve", f"127.0.0.1:{port}", "--duration", "0.1"])
    assert code == 1
    assert f"cannot listen on 127.0.0.1:{port}" in one_error_line(err)


# ---------------------------------------------------------------- 6: scan's NMT column


def _nmt_column(out: str) -> dict[int, str]:
    nodes = out.split("identity (1018h)", maxsplit=1)[0]  # the node table (a narrow one has two)
    rows = re.findall(r"^│ (\d+)\s+│ ([^│]+?)\s+│", nodes, re.MULTILINE)
    return {int(node): nmt for node, nmt in rows}


def test_scan_says_why_the_nmt_column_is_empty(capsys: pytest.CaptureFixture[str]) -> None:
    # Fresh simulated drives produce no heartbeat (1017h = 0, as their EDS says).
    assert main(["scan", "--sim", "--listen", "0.2"]) == 0
    out = capsys.readouterr().out
    assert _nmt_column(out) == {1: "no heartbeat", 2: "no heartbeat", 3: "no heartbeat"}
    assert "NMT: nodes 1, 2, 3 send no heartbeat (producer heartbeat time 1017h = 0)" in out


def test_scan_listens_long_enough_for_a_slow_heartbeat(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    from omnican.sim import SimulatedBase

    real = SimulatedBase.from_config.__func__  # type: ignore[attr-defined]

    def slow_heartbeats(cls, cfg, **kw):  # type: ignore[no-untyped-def]
        sim = real(cls, cfg, **kw)
        for drive in sim.drives:  # one heartbeat every 0.8 s: longer than --listen
            drive.node.sdo[0x1017].raw = 800
        return sim

    monkeypatch.setattr(SimulatedBase, "from_config", classmethod(slow_heartbeats))
    assert main(["scan", "--sim", "--listen", "0.2"]) == 0
    out = capsys.readouterr().out
    assert _nmt_column(out) == {1: "PRE-OPERATIONAL", 2: "PRE-OPERATIONAL",
                                3: "PRE-OPERATIONAL"}, out


# ---------------------------------------------------------------- 7: the teleop keys

# teleop_twist_keyboard's moveBindings as (x, y, th): its z column (t/b) left out.
ROS_MOVE_BINDINGS = {
    "i": (1, 0, 0), "o": (1, 0, -1), "j": (0, 0, 1), "l": (0, 0, -1),
    "u": (1, 0, 1), ",": (-1, 0, 0), ".": (-1, 0, 1), "m": (-1, 0, -1),
    "O": (1, -1, 0), "I": (1, 0, 0), "J": (0, 1, 0), "L": (0, -1, 0),
    "U": (1, 1, 0), "<": (-1, 0, 0), ">": (-1, -1, 0), "M": (-1, 1, 0),
}
ROS_SPEED_BINDINGS = {"q": (1.1, 1.1), "z": (0.9, 0.9), "w": (1.1, 1), "x": (0.9, 1),
                      "e": (1, 1.1), "c": (1, 0.9)}


def test_the_key_map_is_teleop_twist_keyboards() -> None:
    from omnican.command.teleop import MOVE_BINDINGS, SPEED_BINDINGS

    assert MOVE_BINDINGS == ROS_MOVE_BINDINGS
    assert SPEED_BINDINGS == ROS_SPEED_BINDINGS


@pytest.mark.parametrize(("key", "where"), [
    ("u", "forward-left"), ("i", "forward"), ("o", "forward-right"),
    ("j", "turn left"), ("k", "stop"), ("l", "turn right"),
    ("m", "back-left"), (",", "back"), (".", "back-right"),
    ("U", "forward-left"), ("I", "forward"), ("O", "forward-right"),
    ("J", "left"), ("K", "stop"), ("L", "right"),
    ("M", "back-left"), ("<", "back"), (">", "back-right"),
])
def test_each_key_goes_where_the_help_says(key: str, where: str) -> None:
    from omnican import Displacement, Pose2D
    from omnican.command.teleop import TeleopModel, key_direction

    assert key_direction(key) == where
    # And the base really goes there: one second of the key's command from the origin.
    m = TeleopModel(0.3, 1.0, 1.0, 5.0, 0.0)
    m.press(key, 0.0)
    end = Pose2D.exp(Displacement.of(m.command(0.0), 1.0))
    along = "forward" if end.x > 1e-6 else "back" if end.x < -1e-6 else ""
    side = "left" if end.y > 1e-6 else "right" if end.y < -1e-6 else ""
    expected = "-".join(w for w in (along, side) if w) or (
        "turn left" if end.theta > 0 else "turn right" if end.theta < 0 else "stop")
    assert expected == where


def test_the_docs_and_help_show_the_key_map() -> None:
    from omnican.command.teleop import key_help

    block = key_help()
    assert "m    ,    .     back-left" in block
    page = (ROOT / "docs" / "getting-started.md").read_text()
    assert f"```\n{block}\n```" in page
    code, out, _ = run_main(["teleop", "--help"])
    assert code == 0
    assert block in out


# ---------------------------------------------------------------- 8: the square closes


def test_the_square_ends_on_a_full_turn(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["drive", "--sim", "--fast", "--square", "0.4", "--speed", "0.4", "--omega", "1.5",
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for pose in (out["pose"], out["true_pose"]):  # odometry, and where the base really is
        assert math.degrees(pose["theta"]) == pytest.approx(360.0, abs=0.3), out
        assert math.hypot(pose["x"], pose["y"]) < 0.01, out


def test_a_slipping_ground_from_the_config_turns_the_truth_and_the_gyro_sees_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """[sim.slip] under --sim: the right wheel loses 15 % of its travel on the ground. Its
    encoder still counts every turn, so the wheels' pose goes straight on, while the base
    really turns; the pose fused with the simulated gyro turns with it (and says so).
    Without the table the ground grips: the truth is the wheels' pose."""
    text = (ROOT / "examples" / "imu.toml").read_text()
    text = text[:text.index("[sim.gyro]")]  # a gyro without bias or noise
    plain, slipping = tmp_path / "grips.toml", tmp_path / "slips.toml"
    plain.write_text(text)
    slipping.write_text(text + "\n[sim.slip]\nratio = [0.0, 0.15, 0.0]\n")

    def drive(config: Path) -> dict[str, Any]:
        assert main(["drive", "--sim", "--fast", "--config", str(config), "--vx", "0.3",
                     "--duration", "5", "--json"]) == 0
        out: dict[str, Any] = json.loads(capsys.readouterr().out)
        return out

    grips = drive(plain)
    assert grips["true_pose"]["theta"] == pytest.approx(grips["pose"]["theta"], abs=1e-3)
    assert grips["true_pose"]["y"] == pytest.approx(grips["pose"]["y"], abs=1e-3)
    slips = drive(slipping)
    assert slips["pose"]["theta"] == pytest.approx(0.0, abs=1e-3)  # the wheels: straight on
    assert slips["true_pose"]["theta"] < -0.2, slips  # the right wheel held back: it turned
    assert slips["fused_pose"]["theta"] == pytest.approx(slips["true_pose"]["theta"],
                                                         abs=0.05), slips
    assert main(["drive", "--sim", "--fast", "--config", str(slipping), "--vx", "0.3",
                 "--duration", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1].startswith("fused pose x=") and lines[-1].endswith("(wheels and gyro)")
    assert lines[-2].startswith("pose x=") and "true pose" in lines[-3]


# ---------------------------------------------------------------- 9: the display


def test_no_negative_zero_anywhere() -> None:
    from omnican import Pose2D
    from omnican.cli.drive import pose_dict, pose_line

    assert pose_line(Pose2D(-1e-7, -0.0, -4e-6)) == "pose x=0.0000 y=0.0000 theta=0.0000"
    assert pose_line(Pose2D(-0.00005, 0.00004, -1.25)) == "pose x=-0.0001 y=0.0000 theta=-1.2500"
    assert json.dumps(pose_dict(Pose2D(-1e-9, -0.0, -0.0))) == \
        '{"x": 0.0, "y": 0.0, "theta": 0.0}'
    # A motion along +x only: its y, theta and side speeds are zero, and print as such.
    code, out, _ = run_main(["drive", "--sim", "--vx", "0.2", "--duration", "0.3"])
    assert code == 0
    assert not re.search(r"-0\.0+(?![0-9])", out), out
    code, out, _ = run_main(["drive", "--sim", "--vx", "0.2", "--duration", "0.3", "--json"])
    assert code == 0 and "-0.0," not in out and "-0.0}" not in out, out


def test_drive_prints_the_pose_after_ctrl_c() -> None:
    import os
    import signal
    import subprocess
    import time

    proc = subprocess.Popen([sys.executable, "-m", "omnican", "drive", "--sim", "--vx", "0.2",
                             "--duration", "30", "-v"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.stderr is not None
    try:
        lines = []  # up and driving: its drives enabled (however long that took here)
        while not any("every drive enabled" in line for line in lines):
            line = proc.stderr.readline()
            assert line, "".join(lines)
            lines.append(line)
        time.sleep(1.0)  # 0.2 m at 0.2 m/s
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
        err = "".join(lines) + err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    pose = re.search(r"^pose x=(\S+) y=\S+ theta=\S+$", out, re.MULTILINE)
    assert pose is not None, out
    assert float(pose[1]) > 0.05  # it had driven, and says where it stopped
    assert "interrupted" in err


def _teleop(*args: str, columns: int = 120):  # type: ignore[no-untyped-def]
    from tests.cli.test_cli import Pty

    return Pty("--sim", *args, columns=columns)


def test_teleop_shows_recovered_and_the_sim_bus_load() -> None:
    term = _teleop()
    try:
        screen = term.wait_for("RUNNING")
        # the simulated bus has the demo base's nominal bitrate (issue 36): a share of it
        assert re.search(r"bus \d+% of 500 kbit/s", screen), screen
        term.keys("r")
        term.wait_for("recovered")
        term.keys("\x1b")
        assert term.exit_code() == 0
    finally:
        term.close()


def test_teleop_key_help_wraps_between_phrases_at_80_columns() -> None:
    from omnican.cli.dashboard import HELP_PHRASES

    term = _teleop(columns=80)
    try:
        term.wait_for("RUNNING")
        term.screen = ""
        term.keys("k")
        screen = term.wait_for("last key 'k'")
        term.keys("\x1b")
        assert term.exit_code() == 0
    finally:
        term.close()
    for phrase in HELP_PHRASES:
        assert phrase in screen, (phrase, screen[-2500:])


# ---------------------------------------------------------------- 10: help for a new user


def _all_help() -> dict[str, str]:
    from omnican.cli import SUBCOMMANDS

    pages = {}
    for argv in (["--help"], *([name.replace("_", "-"), "--help"] for name in SUBCOMMANDS)):
        code, out, _ = run_main(argv)
        assert code == 0
        pages[" ".join(argv)] = out
    return pages


def test_help_and_docs_speak_to_a_new_user() -> None:
    pages = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md"))]
    assert len(pages) > 10
    texts = {**_all_help(), **{p.name: p.read_text() for p in pages}}
    for name, text in texts.items():
        rst = re.search(r"(?<!`)``(?!`)", text)  # reStructuredText literals (not ``` fences)
        assert rst is None, (name, text[rst.start() - 80:rst.end() + 80])
        assert not re.search(r"\bseeds?\b(?!=)", text, re.IGNORECASE), (
            name, re.findall(r".{0,60}\bseeds?\b.{0,60}", text, re.IGNORECASE))
        assert ":class:" not in text and ":func:" not in text, name


# ---------------------------------------------------------------- 11: speeds beyond the limits


def test_a_speed_beyond_the_limits_is_driven_at_the_limit_with_one_warning() -> None:
    from omnican import Twist, default_config

    code, out, err = run_main(["drive", "--sim", "--fast", "--vx", "100", "--duration", "1.6", "--json"])
    assert code == 0
    warnings = [line for line in err.splitlines() if line.strip()]
    assert len(warnings) == 1, err
    cfg = default_config()
    # The fastest straight-ahead speed: the fastest wheel at its maximum rim speed.
    limit = cfg.chassis.max_wheel_speed / max(abs(cfg.kinematics().to_wheel_speeds(
        Twist(1.0, 0.0, 0.0))))
    assert warnings[0] == (
        "omnican: warning: vx=100 vy=0 wz=0 is beyond the base's limits "
        f"(chassis.max_wheel_speed {cfg.chassis.max_wheel_speed:g} m/s at the rim): "
        f"driving vx={limit:.3f} vy=0.000 wz=0.000")
    assert json.loads(out)["twist"]["vx"] == pytest.approx(limit, abs=0.1)


def test_a_speed_within_the_limits_warns_nothing() -> None:
    code, _, err = run_main(["drive", "--sim", "--vx", "0.3", "--duration", "0.2"])
    assert code == 0 and err == ""


# ---------------------------------------------------------------- 12: unknown config keys


@pytest.mark.parametrize(("old", "new", "message"), [
    ("base_radius = 0.19", "base_radus = 0.19",
     "chassis.base_radus: unknown key 'base_radus' (did you mean 'base_radius'?)"),
    ("node_id = 1\n", "node_id = 1\nvelocity_scal = 3.0\n",
     "wheel[0].velocity_scal: unknown key 'velocity_scal' (did you mean 'velocity_scale'?)"),
    ("base_radius = 0.19", "base_radius = 0.19\ncolour = 'red'",
     "chassis.colour: unknown key 'colour' (the keys: omnican check-config --help)"),
    ("[chassis]", "[chasis]",
     "chasis: unknown section 'chasis' (did you mean 'chassis'?)"),
])
def test_an_unknown_config_key_is_named_with_a_suggestion(tmp_path: Path, old: str, new: str,
                                                          message: str) -> None:
    text = EXAMPLE.read_text()
    assert old in text
    cfg = tmp_path / "robot.toml"
    cfg.write_text(text.replace(old, new, 1))
    code, _, err = run_main(["check-config", str(cfg)])
    assert code == 2
    line = one_error_line(err)
    assert line == f"omnican: error: {cfg}: {message}"


def test_check_config_help_lists_every_key() -> None:
    from omnican.config import SCHEMA

    code, out, _ = run_main(["check-config", "--help"])
    assert code == 0
    for section, keys in SCHEMA.items():
        for key in keys:
            assert f"{section}.{key}" in out, (section, key)
