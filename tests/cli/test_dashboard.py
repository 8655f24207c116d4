"""The teleop dashboard at the terminal's edges (issue 36 item 10): events wrapped, not
cut; numbers never cut to ``+0.…``; the state line the last thing to go; a window too
small says so. Drawn from a stand-in base of the value types the real one hands out."""

from __future__ import annotations

import io
import re
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from rich.console import Console
from rich.screen import Screen

from omnican import Pose2D, Twist, default_config
from omnican.chassis.state import ChassisStatus, WheelState
from omnican.cli.dashboard import dashboard
from omnican.cli.terminal import EVENT_INDENT, RecentEvents, event_lines
from omnican.command.teleop import TeleopModel
from omnican.protocol.cia402 import State

ESTOP = "e-stop pressed (node 1 Digital inputs (0x60FD:00) bit 16)"
REFUSED = f"recover refused: {ESTOP}: release it first"
KEYS = TeleopModel.for_config(default_config(), 0.3, 1.0, 0.6)


def wheel(index: int, online: bool = True) -> WheelState:
    return WheelState(index, index + 1, 0, State.OPERATION_ENABLED, 0x1637, 3, 0.26, -0.259,
                      12.5, online, None, None, current_a=0.7, voltage_v=23.9,
                      temperature_c=25.4)


@dataclass
class StandIn:
    """What the dashboard reads of a base."""

    stopped_reason: str | None = None
    pose: Pose2D = field(default_factory=lambda: Pose2D(12.345, -3.21, 1.5))
    twist: Twist = field(default_factory=lambda: Twist(0.3, 0.0, -0.25))
    command: Twist = field(default_factory=lambda: Twist(0.3, 0.0, -0.25))
    wheels: tuple[WheelState, ...] = field(default_factory=lambda: tuple(
        wheel(i) for i in range(3)))
    bus: Any = field(default_factory=lambda: SimpleNamespace(bitrate=500_000))
    fused_pose: Pose2D | None = None  # an IMU's gyro fused in (None: no IMU)
    warnings: tuple[str, ...] = ()

    @property
    def status(self) -> ChassisStatus:
        return ChassisStatus(enabled=self.stopped_reason is None,
                             stopped_reason=self.stopped_reason, command_age_s=0.0,
                             loop_hz=100.0, late_fraction=0.0, cycles=1000, bus_load=0.15,
                             bus_bits_per_s=75_000.0, bus_error=None, warnings=self.warnings,
                             battery_v=23.9, battery="ok", estop=self.stopped_reason == ESTOP)


def events(*texts: str) -> RecentEvents:
    out = RecentEvents()
    for text in texts:
        out.say(text)
    return out


def screen(base: Any, width: int, height: int, note: str = "",
           said: RecentEvents | None = None) -> list[str]:
    """The frame as teleop's Live draws it: the dashboard in a screen of width x height."""
    console = Console(width=width, height=height, record=True, color_system=None,
                      file=io.StringIO())
    console.print(Screen(dashboard(base, KEYS, Twist(0.3, 0.0, 0.0), "omnican teleop - "
                                   "simulated base, nodes 1, 2, 3", said or events(), note,
                                   width, height)))
    return console.export_text().splitlines()


def test_a_fused_heading_and_a_slip_warning_show_beside_the_wheels() -> None:
    slip = "the wheels slipping: their yaw rate off the gyro's by 0.075 rad/s for 0.5 s"
    lines = screen(StandIn(fused_pose=Pose2D(12.3, -3.2, 1.25), warnings=(slip,)), 120, 40)
    text = "\n".join(lines)
    assert "θ gyro" in text and "+1.250 rad" in text and "+1.500 rad" in text
    assert slip in text
    narrow = "\n".join(screen(StandIn(fused_pose=Pose2D(0.0, 0.0, 0.5)), 50, 40))
    assert "θ gyro +0.500 rad" in narrow
    assert "θ gyro" not in "\n".join(screen(StandIn(), 120, 40))


def test_an_event_past_80_columns_is_wrapped_whole() -> None:
    """``e-stop pressed (node 1 Digital inputs (0x60FD:00) bi...`` and ``recover refused:
    ... rel...`` were cut at 80 columns, with no way to read the rest."""
    frame = screen(StandIn(ESTOP), 80, 24, note=REFUSED, said=events(f"base stopped: {ESTOP}",
                                                                       REFUSED))
    assert len(frame) <= 24 and max(len(line) for line in frame) <= 80
    panel = frame[next(i for i, line in enumerate(frame) if "─ events ─" in line):]
    text = " ".join(line.strip("│╰╯─ ") for line in panel)
    assert f"base stopped: {ESTOP}" in re.sub(r"\s+", " ", text), "\n".join(frame)
    assert REFUSED in re.sub(r"\s+", " ", text), "\n".join(frame)
    assert "…" not in "\n".join(frame)
    flat = re.sub(r"\s+", " ", " ".join(frame))
    assert f"STOPPED: {ESTOP} - release it, then press r" in flat  # wrapped, not cut
    assert REFUSED in flat  # the note too


def test_an_event_wraps_under_its_text_and_the_newest_fits_first() -> None:
    lines = [f"12:00:0{n} " + "word " * 30 for n in range(3)]
    shown = event_lines(lines, 40, 8)
    assert len(shown) <= 8
    assert shown[-5].startswith("12:00:02 ")  # the newest whole: five lines of 40
    assert all(line.startswith(" " * EVENT_INDENT) for line in shown[-4:])
    tight = event_lines(lines, 40, 2)
    assert tight[0].startswith("12:00:02") and tight[-1].endswith("…")


@settings(max_examples=60, deadline=None)
@given(st.integers(10, 160), st.integers(1, 50), st.booleans())
def test_any_window_keeps_the_state_line_and_never_cuts_a_number(width: int, height: int,
                                                                 stopped: bool) -> None:
    """Below 80x24 the numbers became ``+0.…`` and at 40x12 the RUNNING/STOPPED line was
    gone. In any window: at most its size; the state line there (whole where it fits);
    a number whole or not at all; and when something is left out, a line says so (where
    it has room beside the state)."""
    base = StandIn(ESTOP if stopped else None)
    frame = screen(base, width, height, said=events("recovered: every drive enabled",
                                                    f"base stopped: {ESTOP}"))
    assert len(frame) <= height
    assert max(len(line) for line in frame) <= width
    text = "\n".join(frame)
    assert ("STOPPED" if stopped else "RUNNING") in text, text
    if stopped and height >= 3 and width >= 40:
        assert "STOPPED: e-stop pressed" in text, text
    assert not re.search(r"[+-]\d+\.\d*…", text), text  # no number cut short
    said = " ".join(line.strip() for line in frame)
    if width >= 40 and height >= 6 and "too small" not in said:
        # nothing left out (where there is room to say so beside the state)
        assert all(part in text for part in ("wheels", "events", "pose")), text


def test_80x24_is_whole_and_40x12_says_it_is_too_small() -> None:
    whole = "\n".join(screen(StandIn(), 80, 24, said=events("recovered")))
    assert "too small" not in whole and "+12.345" in whole and "RUNNING" in whole
    small = screen(StandIn(), 40, 12, said=events("recovered"))
    text = " ".join(line.strip() for line in small)
    assert "RUNNING" in text
    assert "window 40x12 is too small" in text and "(80x24 shows it all)" in text
    hidden = re.sub(r"\s+", " ", text.split("is too small", 1)[1])
    assert "hidden" in hidden
    narrow = "\n".join(screen(StandIn(), 60, 30, said=events("recovered")))
    assert "x +12.345 m" in narrow and "applied vx +0.300" in narrow  # lines, not panels
    assert "some columns hidden" in narrow and "+0.70" not in narrow  # the current gave way


def test_a_wheel_gone_offline_reads_so_in_a_narrow_window() -> None:
    base = StandIn("node 2 heartbeat lost", wheels=(wheel(0), wheel(1, online=False), wheel(2)))
    text = "\n".join(screen(base, 36, 14))
    assert "node 2 OFFLINE" in text and "STOPPED: node 2 heartbeat lost" in text


def test_teleop_in_a_40x12_terminal_shows_its_state_and_says_it_is_too_small() -> None:
    """The same, as a user meets it: ``omnican teleop --sim`` in a 40x12 terminal."""
    from tests.support.terminal import Pty

    term = Pty("teleop", "--sim", columns=40, lines=12)
    try:
        frame = term.wait_for_frame("RUNNING", timeout=60)
        text = " ".join(line.strip() for line in frame)
        assert len(frame) <= 12 and max(len(line) for line in frame) <= 40, "\n".join(frame)
        assert "window 40x12 is too small" in text, "\n".join(frame)
        assert not re.search(r"[+-]\d+\.\d*…", text), "\n".join(frame)
        term.keys("\x1b")
        assert term.exit_code() == 0
    finally:
        term.close()
