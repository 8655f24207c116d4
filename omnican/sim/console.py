"""The simulator's console: one line of text, a fault injected (or the truth shown).

``omnican sim`` and ``omnican ros2 --sim`` read these from stdin; tests and scripts call
:func:`command` directly. A line it does not understand changes nothing and gets an
``error: ...`` reply.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

from omnican.sim.base import SimulatedBase
from omnican.sim.drive import SimulatedDrive

# The console's commands: (syntax, what it does), for the banner and 'help'.
COMMANDS = (
    ("fault NODE [CODE]", "EMCY + FAULT (default 0x2310 continuous over-current)"),
    ("reboot NODE", "boot-up, defaults restored, position counter reset"),
    ("heartbeat NODE off|on|periodic", "stop or restart the node's heartbeat (periodic: only "
     "on its period, the first one period after 1017h is written, as lely's drives)"),
    ("freeze NODE", "answer nothing, send nothing (a hung node)"),
    ("thaw NODE", "back to normal after freeze"),
    ("jam NODE[.AXIS]", "the wheel cannot turn (its drive pushes at its current limit)"),
    ("push NODE[.AXIS] M/S", "something turns the wheel at that rim speed (a runaway drive)"),
    ("free NODE[.AXIS]", "the wheel turns again (after jam or push)"),
    ("lift NODE[.AXIS]", "the wheel is off the ground (it moves nothing, draws less current)"),
    ("land NODE[.AXIS]", "the wheel is back on the ground"),
    ("ferror NODE[.AXIS] COUNTS|off", "the drive reports a following error (60F4h, bit 13)"),
    ("cwarrival NODE on|off", "act on a controlword only as one arrives (ros2_canopen's fake "
     "slave): enabled, it moves only once a controlword reaches it in OPERATION ENABLED"),
    ("slowboot NODE SECONDS", "answer an NMT reset with the boot-up that much later (0: at once)"),
    ("slowsdo NODE SECONDS", "answer each SDO request that much later (0: at once)"),
    ("battery VOLTS", "the battery feeding every drive (nominal 24 V)"),
    ("estop on|off", "press or release the e-stop (every drive's input and safe torque off)"),
    ("power", "switch every drive off and on: what it stored (LSS node id, 1010h) comes back, "
     "the rest is lost"),
    ("pose", "print the ground-truth pose"),
    ("help", "list the commands"),
    ("quit", "stop the simulator"),
)
#: the fastest push: far beyond any wheel of a base, short of a meaningless pose
PUSH_LIMIT_M_S = 20.0
_NODE_VERBS = ("fault", "reboot", "heartbeat", "freeze", "thaw", "cwarrival")
_WHEEL_VERBS = ("jam", "push", "free", "lift", "land", "ferror")


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


def wheel_for(sim: SimulatedBase, word: str) -> tuple[SimulatedDrive, int]:
    """``N`` (the node's first axis) or ``N.A`` (its axis A), as the dashboard names them."""
    node, _, axis_word = word.partition(".")
    drive = drive_for(sim, node)
    try:
        axis = int(axis_word) if axis_word else 0
    except ValueError:
        raise ValueError(f"not an axis: {axis_word!r} (e.g. {drive.node_id}.1)") from None
    if not 0 <= axis < drive.num_axes:
        raise ValueError(f"node {drive.node_id} has {drive.num_axes} axis(es), no axis {axis}")
    return drive, axis


def _number(word: str, what: str) -> float:
    try:
        value = float(word)
    except ValueError:
        raise ValueError(f"not a number: {word!r} ({what})") from None
    if not math.isfinite(value):
        raise ValueError(f"not a number: {word!r} ({what})")
    return value


#: the wheel commands without a value: what each does to the drive, and the reply
_WHEEL_STATES: dict[str, tuple[Callable[[SimulatedDrive, int], None], str]] = {
    "jam": (SimulatedDrive.jam, "jammed"),
    "free": (SimulatedDrive.free, "turns freely"),
    "lift": (SimulatedDrive.lift, "off the ground"),
    "land": (SimulatedDrive.land, "on the ground"),
}


def _wheel_command(sim: SimulatedBase, verb: str, rest: list[str]) -> str:
    if not rest:
        raise ValueError(f"{verb} needs a node id (nodes: {_nodes(sim)})")
    drive, axis = wheel_for(sim, rest[0])
    name = f"node {drive.node_id}" + (f".{axis}" if axis else "")
    takes_value = verb in ("push", "ferror")
    if len(rest) != (2 if takes_value else 1):
        raise ValueError(f"{verb} takes a node id" + (" and a value" if takes_value else ""))
    if verb in _WHEEL_STATES:
        change, said = _WHEEL_STATES[verb]
        change(drive, axis)
        return f"{name}: {said}"
    if verb == "push":
        speed = _number(rest[1], "m/s at the rim")
        if abs(speed) > PUSH_LIMIT_M_S:  # 1e9 m/s made the pose a meaningless 193551 rad
            raise ValueError(f"push takes -{PUSH_LIMIT_M_S:g} to {PUSH_LIMIT_M_S:g} m/s at "
                             f"the rim, got {rest[1]!r}")
        drive.push(speed, axis)
        return f"{name}: pushed at {speed:g} m/s"
    if rest[1].lower() == "off":
        drive.clear_following_error(axis)
        return f"{name}: no following error"
    counts = round(_number(rest[1], "position units"))
    if counts == 0:
        raise ValueError("a following error is not 0 (ferror N off clears it)")
    drive.inject_following_error(counts, axis)
    return f"{name}: following error {counts}"


#: the commands that slow a drive down: what each sets, and the reply
_SLOW: dict[str, tuple[Callable[[SimulatedDrive, float], None], str]] = {
    "slowboot": (SimulatedDrive.slow_boot, "boot-up {:g} s after an NMT reset"),
    "slowsdo": (SimulatedDrive.slow_sdo, "SDO answers {:g} s after the request"),
}


def _slow_command(sim: SimulatedBase, verb: str, rest: list[str]) -> str:
    if len(rest) != 2:
        raise ValueError(f"{verb} takes a node id and seconds, e.g. {verb} 2 0.5")
    drive = drive_for(sim, rest[0])
    seconds = _number(rest[1], "seconds")
    if seconds < 0:
        raise ValueError(f"a delay is 0 s or more, got {rest[1]!r}")
    change, said = _SLOW[verb]
    change(drive, seconds)
    return f"node {drive.node_id}: {said.format(seconds)}"


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
        if verb == "power":
            if rest:
                raise ValueError("power takes nothing: it cycles every drive")
            sim.power_cycle()
            return "power cycled: " + _power_state(sim)
        if verb == "pose":
            p = sim.true_pose
            return f"true pose x={_fixed(p.x)} y={_fixed(p.y)} theta={_fixed(p.theta)}"
        if verb in _WHEEL_VERBS:
            return _wheel_command(sim, verb, rest)
        if verb in _SLOW:
            return _slow_command(sim, verb, rest)
        if verb == "battery":
            if len(rest) != 1:
                raise ValueError("battery takes the voltage, e.g. battery 19.5")
            volts = _number(rest[0], "volts")
            if volts < 0:
                raise ValueError(f"a battery voltage is 0 or more, got {rest[0]!r}")
            sim.set_battery(volts)
            return f"battery {volts:g} V"
        if verb == "estop":
            if len(rest) != 1 or rest[0].lower() not in ("on", "off"):
                raise ValueError("estop takes on or off")
            sim.estop(rest[0].lower() == "on")
            return f"e-stop {'pressed' if rest[0].lower() == 'on' else 'released'}"
        if verb not in _NODE_VERBS:
            raise ValueError(f"unknown command {words[0]!r} (try 'help')")
        if verb == "heartbeat" and len(rest) != 2:
            raise ValueError("heartbeat takes a node id and on, off or periodic")
        if verb == "cwarrival" and (len(rest) != 2 or rest[1].lower() not in ("on", "off")):
            raise ValueError("cwarrival takes a node id and on or off")
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
            if state not in ("on", "off", "periodic"):
                raise ValueError(f"heartbeat takes on, off or periodic, not {rest[1]!r}")
            if state == "off":
                drive.stop_heartbeat()
            else:
                drive.start_heartbeat(state == "periodic")
            return f"node {drive.node_id}: heartbeat {state}"
        if verb == "cwarrival":
            on = rest[1].lower() == "on"
            drive.act_on_arrival(on)
            return (f"node {drive.node_id}: " + ("acts on a controlword only as one arrives"
                                                 if on else "acts on the controlword it holds"))
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


def _power_state(sim: SimulatedBase) -> str:
    """Which serial runs as which node now."""
    if sim.lss is None:
        return _nodes(sim)
    return ", ".join(f"serial 0x{serial:08X} " + ("without node id" if node == 0xFF else
                                           f"node {node}")
                     for serial, node in sim.lss.node_ids())


def _fixed(value: float) -> str:
    """Four decimals, and 0 never as -0."""
    text = f"{value:.4f}"
    return "0.0000" if float(text) == 0.0 else text
