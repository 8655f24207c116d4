"""The omnican command through its entry point: drive, check-config, scan, sim, teleop."""

from __future__ import annotations

import contextlib
import io
import json
import logging
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest

from omnican.cli import main
from omnican.sim import SimulatedBase
from tests.support import terminal
from tests.support.helpers import VENDOR_EDS, one_error_line

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "robot.toml"
ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]|\x1b[()][A-Z0-9]|\x1b[=>]")




# ---------------------------------------------------------------- drive


def test_drive_json_under_sim(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["drive", "--sim", "--vx", "0.3", "--duration", "0.6", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"pose", "twist", "duration_s", "true_pose", "wheels"}
    assert out["pose"]["x"] > 0.1
    assert abs(out["pose"]["y"]) < 0.005
    assert out["pose"]["x"] == pytest.approx(out["true_pose"]["x"], abs=0.005)
    assert out["twist"]["vx"] == pytest.approx(0.3, abs=0.03)
    assert out["duration_s"] == pytest.approx(0.6, abs=0.1)


def test_main_gives_the_caller_its_logging_back(capsys: pytest.CaptureFixture[str]) -> None:
    """A program (or a test) that calls main() keeps its own logging: no handler of the
    command's is left writing to a stderr that may be gone, and the levels are as set."""
    root = logging.getLogger()
    mine = logging.StreamHandler(io.StringIO())
    root.addHandler(mine)
    before = (list(root.handlers), root.level, logging.getLogger("canopen").level)
    try:
        assert main(["-v", "drive", "--sim", "--fast", "--vx", "0.1", "--duration", "0.2"]) == 0
        assert "every drive enabled" in capsys.readouterr().err  # -v logged, to stderr
        after = (list(root.handlers), root.level, logging.getLogger("canopen").level)
        assert after == before
        logging.getLogger("omnican").warning("after main")
        assert "after main" in mine.stream.getvalue()
        assert "after main" not in capsys.readouterr().err
    finally:
        root.removeHandler(mine)


def test_drive_polar_form(capsys: pytest.CaptureFixture[str]) -> None:
    # 0.3 m/s at 90 deg: straight to the left, at the physical speed (not 2/3 of it).
    assert main(["drive", "--sim", "--fast", "--speed", "0.3", "--heading-deg", "90",
                 "--duration", "0.6", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["twist"]["vy"] == pytest.approx(0.3, abs=0.03)
    assert abs(out["pose"]["x"]) < 0.005


def test_drive_square_closes(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["drive", "--sim", "--fast", "--square", "0.2", "--speed", "0.4", "--omega",
                 "2.0"]) == 0
    out = capsys.readouterr().out.splitlines()
    pose = re.fullmatch(r"pose x=(\S+) y=(\S+) theta=(\S+)", out[-1])
    assert pose is not None
    x, y, theta = (float(v) for v in pose.groups())
    assert abs(x) < 0.02 and abs(y) < 0.02
    assert theta == pytest.approx(2 * 3.14159, abs=0.1)


def test_drive_fast_is_simulated_time_identical_run_to_run(
        capsys: pytest.CaptureFixture[str]) -> None:
    """--fast runs the simulation in lock-step: a 14 s square in a fraction of that, with
    the odometry as good as in real time, and the same numbers every run."""
    argv = ["drive", "--sim", "--fast", "--square", "0.5", "--json"]
    assert main(argv) == 0
    first = json.loads(capsys.readouterr().out)
    assert main(argv) == 0
    second = json.loads(capsys.readouterr().out)
    assert first == second
    assert first["duration_s"] > 10  # simulated seconds
    pose, truth = first["pose"], first["true_pose"]
    assert abs(pose["x"] - truth["x"]) < 0.001 and abs(pose["y"] - truth["y"]) < 0.001
    assert abs(truth["x"]) < 0.01 and abs(truth["y"]) < 0.01  # the square closed


@pytest.mark.parametrize(("argv", "message"), [
    (["drive", "--fast", "--vx", "0.1", "-i", "virtual", "-c", "x"], "add --sim"),
    (["drive", "--sim", "--fast", "--sim-speed", "2", "--vx", "0.1"], "not both"),
])
def test_simulated_time_needs_sim(argv: list[str], message: str,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    assert message in one_error_line(capsys.readouterr().err)


def test_drive_records_the_bus(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import can

    log = tmp_path / "run.log"
    assert main(["drive", "--sim", "--fast", "--vy", "0.2", "--duration", "0.3",
                 "--record", str(log)]) == 0
    ids = {m.arbitration_id for m in can.LogReader(str(log))}
    assert {0x80, 0x201, 0x202, 0x203, 0x281, 0x77F} <= ids


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["drive", "--vx", "nan"], "argument --vx: must be a finite number, got 'nan'"),
        (["drive", "--vx", "fast"], "argument --vx: not a number: 'fast'"),
        (["drive", "--duration", "-1"], "argument --duration: must be positive"),
        (["drive", "--vx", "0.1", "--speed", "0.2"], "give either --vx/--vy/--wz or --speed"),
        (["drive", "--square", "1", "--vx", "1"], "--square takes only --speed and --omega"),
        (["drive", "--sim", "--vx", "0.1", "--config", "/nonexistent.toml"], "cannot read config"),
        (["drive", "--sim", "--vx", "0.1", "--record", "out.weird"], "cannot record to out.weird"),
        (["drive", "--sim", "--vx", "0.1", "-i", "virtual"], "--sim runs on its own virtual bus"),
        (["nosuchcommand"], "invalid choice: 'nosuchcommand'"),
        # Issue 36 item 9: a traceback (a leg of inf seconds), and runs of days or more.
        (["drive", "--sim", "--fast", "--square", "1e308"],
         "motion refused: --square 1e+308: 1e+308 m of travel is beyond what one motion may "
         "take (at most 1e+06 m"),
        (["drive", "--sim", "--fast", "--square", "1e200"], "1e+200 m of travel is beyond"),
        (["drive", "--sim", "--fast", "--square", "1e6"],
         "--square 1e+06: 1e+06 m at 0.3 m/s would take 38.6 days; one motion may take at "
         "most 24 h"),
        (["drive", "--sim", "--fast", "--square", "1e5", "--speed", "5"],
         "the motion would take 4.01 days at the speeds this base drives it"),
        (["drive", "--sim", "--fast", "--vx", "0.1", "--duration", "1e308"],
         "1e+307 m of travel is beyond"),
        (["drive", "--sim", "--fast", "--wz", "0.5", "--duration", "1e7"],
         "5e+06 rad of turning is beyond"),
        (["drive", "--sim", "--fast", "--vx", "0", "--duration", "1e9"],
         "the motion would take 31.7 years"),
    ],
)
def test_bad_usage_is_one_line_and_exit_2(argv: list[str], message: str,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        code = main(argv)
        raise SystemExit(code)
    assert info.value.code == 2
    assert message in one_error_line(capsys.readouterr().err)


@pytest.fixture
def sims(monkeypatch: pytest.MonkeyPatch) -> list[SimulatedBase]:
    """The simulated bases that --sim starts, so a test can inject faults into them."""
    started: list[SimulatedBase] = []
    real = SimulatedBase.from_config.__func__  # type: ignore[attr-defined]

    def recording(cls, cfg, **kw):  # type: ignore[no-untyped-def]
        sim = real(cls, cfg, **kw)
        started.append(sim)
        return sim

    monkeypatch.setattr(SimulatedBase, "from_config", classmethod(recording))
    return started


def test_drive_fault_exits_1(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
                             sims: list[SimulatedBase]) -> None:
    """A drive faulting mid-run: one line on stderr, the pose so far, exit 1."""
    from omnican.cli import drive as drive_cli

    real = drive_cli.execute

    def faulting(base, plan):  # type: ignore[no-untyped-def]
        sims[0].drives[1].inject_fault(0x4310)
        return real(base, plan)

    monkeypatch.setattr(drive_cli, "execute", faulting)
    assert main(["drive", "--sim", "--vx", "0.2", "--duration", "1.0"]) == 1
    captured = capsys.readouterr()
    errors = [line for line in captured.err.splitlines() if "error:" in line]
    assert errors == ["omnican: error: base stopped: node 2 fault: 0x4310 excess temperature "
                      "drive"]
    assert "Traceback" not in captured.err
    assert captured.out.startswith("pose x=")


# ---------------------------------------------------------------- check-config


def test_check_config_prints_plan_and_load(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check-config", str(EXAMPLE)]) == 0
    out = capsys.readouterr().out
    assert f"{EXAMPLE}: OK" in out
    assert ("RPDO1 0x201 every SYNC, 6 bytes: Target velocity (0x60FF:00), Controlword "
            "(0x6040:00)") in out
    assert "TPDO2 0x283 every SYNC, 4 bytes: Position actual value (0x6064:00)" in out
    assert "685 worst-case bits per cycle" in out
    # The health values every 20th SYNC: two 8- and 5-byte TPDOs per node at 5 Hz.
    assert ("health TPDO3 0x381 every 20 SYNCs, 8 bytes: Current actual value (0x6078:00), "
            "Torque actual value (0x6077:00), DC link circuit voltage (0x6079:00)") in out
    assert "health reads (5 Hz): 3.60 kbit/s of that, 0.72% of 500 kbit/s" in out
    assert "bus load at 500 kbit/s: 15%" in out


def test_check_config_vendor_drives(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "zlac.toml"
    cfg.write_text(
        '[bus]\ninterface = "socketcan"\nchannel = "can0"\nbitrate = 1000000\n'
        '[chassis]\nlayout = "b21"\nbase_radius = 0.2\n'
        + "".join(f'[[wheel]]\nnode_id = {n}\naxis = {a}\neds = "{VENDOR_EDS}/zlac8015d.eds"\n'
                  "velocity_scale = 100.0\nposition_scale = 1000.0\n"
                  for n, a in ((1, 0), (1, 1), (2, 0))))
    assert main(["check-config", str(cfg)]) == 0
    out = capsys.readouterr().out
    assert "warning: no heartbeat consumer (1016h)" in out
    assert ("RPDO1 0x201 every SYNC, 8 bytes: Left Motor Target_velocity (0x60FF:01), "
            "Right Motor Target_velocity (0x60FF:02)") in out
    assert "RPDO2 0x301 every SYNC, 2 bytes: Controlword (0x6040:00)" in out
    assert "Statusword (0x6041:00)" in out and "bus load at 1000 kbit/s" in out


def test_check_config_problems_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(EXAMPLE.read_text().replace("node_id = 3", "node_id = 300"))
    assert main(["check-config", str(bad)]) == 2
    assert "wheel[2].node_id: must be 1-127, got 300" in one_error_line(capsys.readouterr().err)
    fast = tmp_path / "fast.toml"
    fast.write_text(EXAMPLE.read_text().replace("rate_hz = 100 ", "rate_hz = 1000 "))
    assert main(["check-config", str(fast)]) == 2
    assert "bus load above 80 %" in capsys.readouterr().err


# ---------------------------------------------------------------- scan


def test_scan_finds_the_configured_nodes(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["scan", "--sim", "--listen", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "3 node(s) found; 0 configured node(s) missing" in out
    for node in (1, 2, 3):
        assert re.search(rf"│ {node} .*0x00020192.*profile velocity.*│ ok", out), out


def test_scan_flags_a_missing_node(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                   monkeypatch: pytest.MonkeyPatch,
                                   sims: list[SimulatedBase]) -> None:
    cfg = tmp_path / "four.toml"
    cfg.write_text("[chassis]\nbase_radius = 0.2\n" + "".join(
        f"[[wheel]]\nnode_id = {n}\nangle_deg = {a}\nvelocity_scale = 1.0\nposition_scale = 1.0\n"
        for n, a in ((1, 0), (2, 90), (3, 180), (4, 270))))
    from omnican.cli import scan as scan_cli

    real = scan_cli.scan

    def without_node_4(cfg, listen_s, sdo_timeout, layouts):  # type: ignore[no-untyped-def]
        sims[0].drives[3].freeze()  # powered off, as far as the bus can tell
        return real(cfg, listen_s, sdo_timeout, layouts)

    monkeypatch.setattr(scan_cli, "scan", without_node_4)
    assert main(["scan", "--sim", "--config", str(cfg), "--listen", "0.2"]) == 1
    out = capsys.readouterr().out
    assert re.search(r"│ 4 +│ no answer .*│ MISSING \(configured\) +│", out), out
    assert "3 node(s) found; 1 configured node(s) missing" in out


# ---------------------------------------------------------------- sim + a client process


class Lines:
    """Lines of a child's stdout, read without blocking past a timeout."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        assert proc.stdout is not None
        self.fd = proc.stdout.fileno()
        self.buffer = b""

    def next(self, timeout: float = 10.0) -> str:
        end = time.monotonic() + timeout
        while b"\n" not in self.buffer:
            ready, _, _ = select.select([self.fd], [], [], max(0.0, end - time.monotonic()))
            assert ready, f"no line from the child within {timeout} s: {self.buffer!r}"
            chunk = os.read(self.fd, 4096)
            assert chunk, f"the child closed its output: {self.buffer!r}"
            self.buffer += chunk
        line, self.buffer = self.buffer.split(b"\n", 1)
        return line.decode()


def test_sim_serves_another_process(capsys: pytest.CaptureFixture[str]) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "omnican", "sim", "--serve", "127.0.0.1:0"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=env)
    lines = Lines(proc)
    assert proc.stdin is not None

    def say(text: str) -> None:
        assert proc.stdin is not None
        proc.stdin.write(text.encode())
        proc.stdin.flush()

    try:
        first = lines.next()
        assert first.startswith("serving simulated nodes 1 (omnican_wheel.eds), 2")
        url = re.search(r"on (ws://127\.0\.0\.1:\d+/)", first)
        assert url is not None
        assert lines.next() == f"connect with: omnican teleop -i remote -c {url[1]}"
        assert lines.next().startswith("type a command here: fault NODE [CODE], reboot NODE")
        assert main(["drive", "-i", "remote", "-c", url[1], "--vx", "0.3", "--duration", "0.5",
                     "--json"]) == 0
        pose = json.loads(capsys.readouterr().out)["pose"]
        assert pose["x"] > 0.1
        say("pose\n")
        true = re.fullmatch(r"true pose x=(\S+) y=(\S+) theta=(\S+)", lines.next())
        assert true is not None and float(true[1]) == pytest.approx(pose["x"], abs=0.01)
        say("fault 9\n")
        assert lines.next().startswith("error: no simulated node 9")
        say("quit\n")
        assert lines.next() == "simulator stopped"
        _, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert b"Traceback" not in err


def test_sim_refuses_a_non_loopback_address(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "--serve", "8.8.8.8:5000", "--duration", "0.1"]) == 2
    assert "the hub serves loopback only" in one_error_line(capsys.readouterr().err)


# ---------------------------------------------------------------- teleop


def test_teleop_needs_a_terminal(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["teleop", "--sim"]) == 2
    assert "stdin is not one" in one_error_line(capsys.readouterr().err)


class Pty(terminal.Pty):
    """omnican teleop in a pseudo-terminal: send keys, read the screen."""

    def __init__(self, *args: str, columns: int = 120, lines: int = 40) -> None:
        super().__init__("teleop", *args, columns=columns, lines=lines)


@pytest.mark.skipif(shutil.which("stty") is None and sys.platform != "linux",
                    reason="needs a POSIX pseudo-terminal")
def test_teleop_drives_from_the_keyboard() -> None:
    term = Pty("--sim")
    try:
        screen = term.wait_for("RUNNING")
        assert "OPERATION ENABLED" in screen and "wheels" in screen
        end = time.monotonic() + 1.2
        while time.monotonic() < end:  # hold 'i' (forward), as key repeat would
            term.keys("i")
            term.read(0.05)
        screen = term.wait_for("last key 'i'")
        term.screen = ""
        term.keys("J")  # Shift: strafe left
        screen = term.wait_for("last key 'J'")
        term.keys("q")  # all speeds +10 %
        screen = term.wait_for("speed 0.33 m/s   turn 1.10 rad/s")
        time.sleep(1.0)  # key timeout: the base stops by itself
        term.keys("\x1b")  # Esc quits
        assert term.exit_code() == 0
        final = term.read(0.5).strip().splitlines()[-1]
        match = re.fullmatch(r"pose x=(\S+) y=(\S+) theta=(\S+)", final.strip())
        assert match is not None, final
        assert float(match[1]) > 0.15  # drove forward
        assert float(match[2]) > 0.01  # then strafed left
        assert abs(float(match[3])) < 0.01  # without turning
    finally:
        term.close()


def test_teleop_ctrl_c_quits_with_the_pose() -> None:
    term = Pty("--sim")
    try:
        term.wait_for("RUNNING")
        term.keys("\x03")  # Ctrl-C
        assert term.exit_code() == 0
        assert re.search(r"pose x=\S+ y=\S+ theta=\S+", term.read(0.5))
    finally:
        term.close()


def test_teleop_keeps_ctrl_c_from_discarding_what_it_prints_and_gives_the_flag_back() -> None:
    """A Ctrl-C makes the terminal discard the output not yet shown: a second one right
    after the final pose was printed, with the terminal behind (ssh to a loaded robot,
    or this test beside busy processes), wiped the pose. While a base is open the
    terminal has NOFLSH; a program that ends without a signal gives it back."""
    term = Pty("--sim")
    try:
        assert not termios.tcgetattr(term.master)[3] & termios.NOFLSH
        term.wait_for("RUNNING")
        assert termios.tcgetattr(term.master)[3] & termios.NOFLSH
        term.keys("\x1b")  # Esc quits without a signal
        assert term.exit_code() == 0
        assert not termios.tcgetattr(term.master)[3] & termios.NOFLSH
    finally:
        term.close()


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash for job control")
def test_drive_in_the_background_of_a_terminal_runs_to_the_end() -> None:
    """A background job that changes its terminal's settings is stopped (SIGTTOU): the
    NOFLSH above is set only by a program in the terminal's foreground."""
    job = (f"set -m; {sys.executable} -m omnican drive --sim --vx 0.1 --duration 0.3 & "
           "wait $!; echo rc=$?")
    term = terminal.Pty(argv=["bash", "-c", job])
    try:
        assert term.exit_code(timeout=60) == 0
        text = term.read(0.2)
        assert "rc=0" in text, text[-2000:]
        assert re.search(r"^pose x=\S+ y=\S+ theta=\S+", text, re.M)
    finally:
        term.close()


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash for job control")
def test_teleop_ctrl_z_then_fg_still_takes_keys_without_enter() -> None:
    """Issue 31 item 7: Ctrl-Z then fg left teleop deaf (the shell had reset the terminal:
    keys echoed and arrived only after Enter, Esc did not quit). In an interactive shell,
    with job control as a user has it."""
    term = terminal.Pty(argv=["bash", "--norc", "--noprofile", "-i"])
    try:
        term.keys(f"PS1='$ '; {sys.executable} -m omnican teleop --sim; echo rc=$?\n")
        term.wait_for_frame("RUNNING", timeout=60)
        term.keys("\x1a")  # Ctrl-Z
        term.wait_for_frame("Ctrl-Z: teleop does not suspend")
        term.keys("fg\n")  # what a user types next (keys to teleop when it stayed)
        term.read(0.5)
        term.screen = ""
        term.keys("i")
        term.wait_for_frame("last key 'i'")
        term.keys("\x1b")
        term.wait_for("rc=0")
        assert re.search(r"pose x=\S+ y=\S+ theta=\S+", term.read(0.2))
    finally:
        with contextlib.suppress(OSError):
            term.keys("exit\n")
        term.close()


def test_drive_fast_stopped_by_ctrl_c_reports_no_false_heartbeat_errors() -> None:
    """Issue 31 item 9: SIGTERM (or Ctrl-C) under --fast printed three false "EMCY 0x8130
    heartbeat error" warnings: the control cycle it interrupted had left the clock."""
    term = terminal.Pty("drive", "--sim", "--fast", "--vx", "0.1", "--duration", "80000")
    try:
        term.wait_for("%", timeout=60)  # the progress bar: the base is driving
        term.read(2.0)
        term.proc.send_signal(signal.SIGTERM)
        assert term.exit_code(timeout=60) == 143
        screen = term.read(0.3)
        assert "terminated: the base stopped here" in screen, screen[-2000:]
        assert "EMCY" not in screen and "0x8130" not in screen, screen[-2000:]
    finally:
        term.close()


@pytest.mark.parametrize("gap_s", [0.05, 0.3])
def test_teleop_ctrl_c_twice_still_quits_with_the_pose(gap_s: float) -> None:
    """An impatient second Ctrl-C, during the stop or after it while the program shuts
    the simulator down, neither cuts the stop short nor loses the final pose."""
    term = Pty("--sim")
    try:
        term.wait_for("RUNNING")
        term.keys("\x03")
        time.sleep(gap_s)
        term.keys("\x03")
        assert term.exit_code() == 0
        assert re.search(r"pose x=\S+ y=\S+ theta=\S+", term.read(0.5))
    finally:
        term.close()
