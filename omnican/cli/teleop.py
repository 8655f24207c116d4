"""omnican teleop: drive the base from the keyboard, with a live dashboard.

The keys are those of ROS's teleop_twist_keyboard (the key map is printed below).
Holding a key keeps the base moving; when keys stop arriving for --key-timeout
seconds it stops. With --gamepad a pad drives instead (ROS teleop_twist_joy's rules: hold
LB/L1, left stick moves, right stick turns, RB/R1 for turbo; releasing LB or unplugging
the pad stops the base); the keys still quit, recover and scale the speeds. On exit every
drive is disabled and the final pose is printed as 'pose x=<m> y=<m> theta=<rad>'.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import time
from collections.abc import Callable
from typing import Any

from rich.console import Console
from rich.live import Live

from omnican.chassis import Chassis
from omnican.chassis.actions import Action, Outcome
from omnican.chassis.arbiter import CommandSource
from omnican.cli import front_ends
from omnican.cli.common import (
    EXIT_FAILURE,
    EXIT_OK,
    UsageError,
    pose_line,
    positive_float,
)
from omnican.cli.dashboard import (
    dashboard,
)
from omnican.cli.session import add_bus_arguments, add_record_argument, session
from omnican.cli.terminal import RecentEvents, Screen, cbreak, logs_into, read_keys
from omnican.command.teleop import Intent, TeleopModel, key_help
from omnican.core.kinematics import Twist
from omnican.gamepad.device import Gamepad, config_table, pad_command, teleop_model_for

LOOP_S = 0.05


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("teleop", help="drive the base from the keyboard (live dashboard)",
                       description=f"{__doc__}\nkeys:\n{key_help()}\n",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--speed", type=positive_float, default=0.3, metavar="M/S",
                   help="initial linear speed (default 0.3)")
    p.add_argument("--turn", type=positive_float, default=1.0, metavar="RAD/S",
                   help="initial turn rate (default 1.0)")
    p.add_argument("--key-timeout", type=float, default=0.6, metavar="S",
                   help="stop when no key arrives for this long (default 0.6; 0: never)")
    add_record_argument(p)
    front_ends.add_arguments(p, "base", inputs=add_gamepad_argument)
    add_bus_arguments(p, sim_help="drive simulated drives in this process (no hardware)")
    p.set_defaults(func=run)


def add_gamepad_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--gamepad", nargs="?", const="", metavar="DEVICE",
                   help="drive with a gamepad (evdev; default: the first one found, or e.g. "
                        "/dev/input/event5): hold LB/L1 to move, RB/R1 for turbo, left stick "
                        "moves, right stick turns; the [gamepad] table of --config maps it")


def beyond_limits(speed: float, turn: float, keys: TeleopModel) -> list[str]:
    """What --speed and --turn asked beyond what the base reaches (as drive warns)."""
    out = []
    if speed > keys.max_speed + 1e-9:
        out.append(f"--speed {speed:g} m/s is beyond the base's limits (it reaches "
                   f"{keys.max_speed:.2f} m/s: chassis.max_speed, max_wheel_speed): starting at "
                   f"{keys.speed:.2f} m/s")
    if turn > keys.max_turn + 1e-9:
        out.append(f"--turn {turn:g} rad/s is beyond the base's limits (it reaches "
                   f"{keys.max_turn:.2f} rad/s: chassis.max_angular_speed, max_wheel_speed): "
                   f"starting at {keys.turn:.2f} rad/s")
    return out


def bus_name(bus: Any) -> str:
    """The bus as the header names it: ``remote ws://127.0.0.1:54701/``, ``socketcan can0``."""
    if not bus:
        return "python-can's configured bus"
    return " ".join(str(bus[k]) for k in ("interface", "channel") if bus.get(k) is not None)


SUSPEND_REFUSED = ("Ctrl-Z: teleop does not suspend (the drives would lose this host's "
                   "heartbeat); Esc quits")

def share_command(source: CommandSource, command: Twist) -> str | None:
    """The local input's command when others (Foxglove) may drive too: a motion goes to
    the base when ``source`` may command (it then holds control); the first zero after
    it goes too (the keys let go: the base stops) and gives control up. Returns who
    refused it (None: not refused)."""
    if not command.is_zero():
        return source.drive(command).refused_by
    source.release(stop=True)  # stops the base only if these keys drove it
    return None


def refusal_note(source: CommandSource, refused: str) -> str:
    """What the dashboard says when ``source``'s command was refused by ``refused``:
    who drives, or who stopped this source (a stop from elsewhere: a Foxglove client's
    ``/omnican/stop``, a Zenoh ``~/stop``, the fleet stop); the stopper does not drive."""
    if source.stopped_by() == refused:
        return (f"{refused} stopped {source.name}: let go for {source.timeout_s:g} s to "
                "drive again")
    return f"{refused} is driving: space stops the base"


def stop_key(source: CommandSource) -> str:
    """The stop key beside other sources: the base stops whoever drives (anyone may);
    the note after it names the driver it stopped, if another drove."""
    stopped = source.stop()
    return f"stopped {stopped}: it drives again once it lets go" if stopped else ""


def recover_key(source: CommandSource, show: Callable[[str], None]) -> Outcome:
    """The recover key: recover through ``source`` if it may (``show`` draws
    ``recovering...`` meanwhile: it takes seconds); the answer, for :func:`recover_note`."""
    asked = source.may(Action.RECOVER)
    if not asked.ok:
        return asked
    show("recovering...")
    return source.recover()


def recover_note(answer: Outcome) -> str:
    """What the dashboard says after the recover key."""
    if answer.refused_by is not None:
        return f"{answer.refused_by} is driving: not recovering"
    said = answer.failed
    if said is None:
        return ""
    return said if said.startswith("recover") else f"recover failed: {said}"


def source_name(gamepad: bool) -> str:
    """The name teleop's source of commands is told to the others by."""
    return "the gamepad" if gamepad else "the terminal's keys"


def drive_loop(base: Chassis, keys: TeleopModel, fd: int, live: Live, title: str,
               events: RecentEvents, pad: Gamepad | None = None, shared: bool = False,
               screen: Screen | None = None) -> None:
    """Keys (or the gamepad) in, commands out, dashboard refreshed, until Esc. When
    ``shared`` (Foxglove may drive too) the keys command only while they move the base
    and no one else drives; a stop key stops the base whoever drives. What the keys may
    do beside the others is the base's to say (its source's answers)."""
    screen = screen or Screen(fd, live)
    note = ""
    note_stop: str | None = None  # the stop a failed recover's note speaks of
    source = base.command_source(source_name(pad is not None))

    def show(text: str) -> None:
        screen.draw(dashboard(base, keys, Twist(), title, events, text,
                              live.console.width, live.console.height))

    while not keys.quit_requested:
        now = time.monotonic()
        if note_stop is not None and base.status.stopped_reason != note_stop:
            note, note_stop = "", None  # a newer stop (or none): the old refusal is stale
        for key in read_keys(fd, LOOP_S if pad is None else LOOP_S / 2):
            stop = keys.press(key, now).intent is Intent.STOP
            if note.startswith("stopped "):
                note = ""  # the next key after it
            if stop and shared:  # whoever drives; it drives again once it lets go
                note = stop_key(source) or note
        if keys.take_recover():
            answer = recover_key(source, show)
            note = recover_note(answer)
            if answer.failed is not None:
                note_stop = base.status.stopped_reason
        if pad is not None:  # the pad moves; the keys still quit, recover and scale
            command = pad_command(pad, keys, LOOP_S / 2)
            shown = note or pad.status_text()
        else:
            command = keys.command(time.monotonic())
            shown = note
        if not shared:  # the only source: every command goes, zeros too
            source.drive(command)
        else:
            refused = share_command(source, command)
            driver = source.holder()
            if refused:
                shown = refusal_note(source, refused)
            elif driver and driver != source.name and not shown:
                shown = f"{driver} is driving"
        screen.draw(dashboard(base, keys, command, title, events, shown, live.console.width,
                              live.console.height))


def run(args: argparse.Namespace) -> int:
    if not sys.stdin.isatty():
        raise UsageError("teleop reads keys from a terminal, and stdin is not one "
                         "(for scripts use 'omnican drive')")
    if not math.isfinite(args.key_timeout) or args.key_timeout < 0:
        raise UsageError(f"--key-timeout must be 0 or more seconds, got {args.key_timeout}")
    fd = sys.stdin.fileno()
    console = Console()
    events = RecentEvents()
    final = None
    failed = False
    pad = None
    if args.gamepad is not None:  # before the drives come up: no pad, nothing moves
        pad = Gamepad.open(args.gamepad or None, config_table(args.config))
    with session(args) as s, (pad or contextlib.nullcontext()):
        if pad is not None:
            keys = teleop_model_for(s.cfg, pad.mapping)
        else:
            keys = TeleopModel.for_config(s.cfg, args.speed, args.turn, args.key_timeout)
            for line in beyond_limits(args.speed, args.turn, keys):
                print(f"omnican: warning: {line}", file=sys.stderr, flush=True)
                events.lines.append(f"{time.strftime('%H:%M:%S')} warning: {line}")
        where = "simulated base" if s.sim else f"base on {bus_name(s.cfg.bus)}"
        nodes = ", ".join(str(n) for n in s.cfg.nodes())
        title = f"omnican teleop - {where}, nodes {nodes}"
        if pad is not None:
            title += f" - gamepad {pad.name}"
        running = front_ends.from_args(args, s.cfg, "base")
        # Foxglove's clients, Zenoh's cmd_vel publishers may drive too
        shared = any(front_end.drives for front_end in running)
        console.print(f"{title}: bringing the drives up...", style="dim")
        front_ends.prepare(running, s.cfg)  # their slow set-up before the control loop runs

        screen = Screen(fd)

        def announce(text: str) -> None:
            console.print(text, style="dim")
            events.lines.append(f"{time.strftime('%H:%M:%S')} {text}")

        with s.open_base(record=args.record) as base, \
                front_ends.attached(running, base, s.sim, announce), \
                cbreak(fd, lambda: events.say(SUSPEND_REFUSED), screen.resumed), \
                logs_into(events), \
                Live(console=console, screen=True, auto_refresh=False, transient=True) as live:
            screen.live = live
            title += front_ends.headlines(running)
            try:
                drive_loop(base, keys, fd, live, title, events, pad, shared, screen)
            except KeyboardInterrupt:  # Ctrl-C quits like Esc
                pass
            base.stop()
        # Leaving the block stopped the wheels and disabled every drive: the pose now
        # includes the stop (read inside the block, it would miss the last samples).
        final = base.pose
        # A drive the close could not confirm disabled (it went OFFLINE, the bus went
        # down: the error above names each) is a failure at run time.
        failed = bool(base.not_disabled)
    if final is not None:
        print(pose_line(final))
    return EXIT_FAILURE if failed else EXIT_OK
