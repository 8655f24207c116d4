"""The simulator's console: one line of text, a fault injected (or the truth shown).

``omnican sim`` and ``omnican ros2 --sim`` read these from stdin; tests and scripts call
:func:`command` directly. A line it does not understand changes nothing and gets an
``error: ...`` reply.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from omnican.sim.base import SimulatedBase
from omnican.sim.drive import SimulatedDrive

# The console's commands: (syntax, what it does), for the banner and 'help'.
COMMANDS = (
    ("fault NODE [CODE]", "EMCY + FAULT (default 0x2310 continuous over-current)"),
    ("reboot NODE", "boot-up, defaults restored, position counter reset"),
    ("heartbeat NODE off|on", "stop or restart the node's heartbeat"),
    ("freeze NODE", "answer nothing, send nothing (a hung node)"),
    ("thaw NODE", "back to normal after freeze"),
    ("pose", "print the ground-truth pose"),
    ("help", "list the commands"),
    ("quit", "stop the simulator"),
)
_NODE_VERBS = ("fault", "reboot", "heartbeat", "freeze", "thaw")


def commands_help() -> str:
    width = max(len(syntax) for syntax, _ in COMMANDS)
    return "\n".join(f"{syntax:<{width}}  {what}" for syntax, what in COMMANDS)


def _nodes(sim: SimulatedBase) -> str:
    return ", ".join(str(d.node_id) for d in sim.drives)


def drive_for(sim: SimulatedBase, word: str) -> SimulatedDrive:
    try:
        node = int(word, 0)
    except ValueError:
        raise ValueError(f"not a node id: {word!r} (nodes: {_nodes(sim)})") from None
    for d in sim.drives:
        if d.node_id == node:
            return d
    raise ValueError(f"no simulated node {node} (nodes: {_nodes(sim)})")


def parse_emcy_code(word: str) -> int:
    try:
        code = int(word, 0)
    except ValueError:
        raise ValueError(f"not an emergency code: {word!r} (e.g. 0x2310)") from None
    if not 0 < code <= 0xFFFF:
        raise ValueError(f"an emergency code is 0x0001-0xFFFF, got {word!r}")
    return code


def command(sim: SimulatedBase, line: str,
            more: Mapping[str, Callable[[], str]] | None = None) -> str | None:
    """Apply one console command; returns the reply ('error: ...' for a command it does
    not understand, which then does nothing), or None to quit. ``more``: commands a
    front end adds (``omnican ros2 --sim``: recover), by verb."""
    words = line.split()
    if not words:
        return ""
    verb, rest = words[0].lower(), words[1:]
    try:
        if verb in ("quit", "exit"):
            return None
        if more and verb in more:
            return more[verb]()
        if verb == "help":
            return commands_help()
        if verb == "pose":
            p = sim.true_pose
            return f"true pose x={_fixed(p.x)} y={_fixed(p.y)} theta={_fixed(p.theta)}"
        if verb not in _NODE_VERBS:
            raise ValueError(f"unknown command {words[0]!r} (try 'help')")
        if verb == "heartbeat" and len(rest) != 2:
            raise ValueError("heartbeat takes a node id and on or off")
        if not rest:
            raise ValueError(f"{verb} needs a node id (nodes: {_nodes(sim)})")
        drive = drive_for(sim, rest[0])
        if verb == "fault":
            if len(rest) > 2:
                raise ValueError("fault takes a node id and an optional code")
            code = parse_emcy_code(rest[1]) if len(rest) > 1 else 0x2310
            drive.inject_fault(code)
            return f"node {drive.node_id}: fault 0x{code:04X}"
        if verb == "heartbeat":
            state = rest[1].lower()
            if state not in ("on", "off"):
                raise ValueError(f"heartbeat takes on or off, not {rest[1]!r}")
            (drive.start_heartbeat if state == "on" else drive.stop_heartbeat)()
            return f"node {drive.node_id}: heartbeat {state}"
        if len(rest) > 1:
            raise ValueError(f"{verb} takes only a node id")
        if verb == "reboot":
            drive.reboot()
            return f"node {drive.node_id}: rebooted"
        if verb == "freeze":
            drive.freeze()
            return f"node {drive.node_id}: frozen"
        drive.thaw()
        return f"node {drive.node_id}: thawed"
    except ValueError as exc:
        return f"error: {exc}"


def _fixed(value: float) -> str:
    """Four decimals, and 0 never as -0."""
    text = f"{value:.4f}"
    return "0.0000" if float(text) == 0.0 else text
