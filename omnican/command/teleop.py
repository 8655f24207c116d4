"""The teleop command model: what keys (or a gamepad) ask for, as a body twist.

Shared by every manual front end: the keyboard's key map (after ROS's
``teleop_twist_keyboard``), speed scales kept within the base's limits, and the rule
that stops the base when input stops: no input for ``timeout_s`` (a key not
repeated, a gamepad gone quiet), or a deadman released, and the command is zero.

A keyboard front end calls :meth:`TeleopModel.press` per key; a gamepad calls
:meth:`TeleopModel.move` with its stick values while the deadman button is held,
:meth:`TeleopModel.release` when it is let go. Both read :meth:`TeleopModel.command`
each cycle and hand it to ``Chassis.set_velocity``.

Pure module: no I/O.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from omnican.config import ChassisConfig
from omnican.core.kinematics import Twist

Direction = tuple[float, float, float]  # (x, y, th) multipliers of (speed, speed, turn)

#: (x, y, th) of each movement key: teleop_twist_keyboard's moveBindings without its
#: z column (t/b move up and down, which a base cannot). Lower case turns, Shift strafes.
MOVE_BINDINGS: dict[str, tuple[int, int, int]] = {
    "i": (1, 0, 0), "o": (1, 0, -1), "j": (0, 0, 1), "l": (0, 0, -1),
    "u": (1, 0, 1), ",": (-1, 0, 0), ".": (-1, 0, 1), "m": (-1, 0, -1),
    "O": (1, -1, 0), "I": (1, 0, 0), "J": (0, 1, 0), "L": (0, -1, 0),
    "U": (1, 1, 0), "<": (-1, 0, 0), ">": (-1, -1, 0), "M": (-1, 1, 0),
}
#: (linear factor, angular factor) of each speed key: teleop_twist_keyboard's speedBindings.
SPEED_BINDINGS: dict[str, tuple[float, float]] = {
    "q": (1.1, 1.1), "z": (0.9, 0.9), "w": (1.1, 1.0), "x": (0.9, 1.0),
    "e": (1.0, 1.1), "c": (1.0, 0.9),
}
ESC, CTRL_C = "\x1b", "\x03"
STOP_KEYS = frozenset({"k", "K", " "})
RECOVER_KEYS = frozenset({"r", "R"})
QUIT_KEYS = frozenset({ESC, CTRL_C})


class Intent(enum.Enum):
    """What one key asks for."""

    MOVE = "move"
    SPEED = "speed"
    STOP = "stop"
    RECOVER = "recover"
    QUIT = "quit"


@dataclass(frozen=True)
class KeyAction:
    intent: Intent
    direction: tuple[int, int, int] = (0, 0, 0)  # MOVE
    factors: tuple[float, float] = (1.0, 1.0)  # SPEED: (linear, angular)


def key_action(key: str) -> KeyAction:
    """The action of one key; any key without a binding stops, as in
    teleop_twist_keyboard."""
    if key in MOVE_BINDINGS:
        return KeyAction(Intent.MOVE, direction=MOVE_BINDINGS[key])
    if key in SPEED_BINDINGS:
        return KeyAction(Intent.SPEED, factors=SPEED_BINDINGS[key])
    if key in RECOVER_KEYS:
        return KeyAction(Intent.RECOVER)
    if key in QUIT_KEYS:
        return KeyAction(Intent.QUIT)
    return KeyAction(Intent.STOP)


def speed_limits(cfg: ChassisConfig) -> tuple[float, float]:
    """(linear m/s, angular rad/s) that the base can really reach: its speed limits,
    and what its fastest wheel allows for pure translation or pure rotation."""
    c = cfg.chassis
    kin = cfg.kinematics()
    return (min(c.max_speed, c.max_wheel_speed),
            min(c.max_angular_speed, c.max_wheel_speed / max(kin.base_radius)))


def key_direction(key: str) -> str:
    """Where a key takes the base, seen from above: ``forward-left``, ``back``, ``turn
    left``, ``stop``... (a turning key's path curves: ``m``, back while turning right,
    ends behind and to the left, as a car reversing with the wheel turned right)."""
    if key not in MOVE_BINDINGS:
        return "stop" if key in STOP_KEYS else ""
    x, y, th = MOVE_BINDINGS[key]
    if x == 0 and y == 0:
        return "turn left" if th > 0 else "turn right" if th < 0 else "stop"
    # One radian of turn (or none) while moving: where the path ends.
    end_y = y if th == 0 else x * (1 - math.cos(th)) / th + y * math.sin(th) / th
    end_x = x if th == 0 else x * math.sin(th) / th - y * (1 - math.cos(th)) / th
    along = "forward" if end_x > 0 else "back" if end_x < 0 else ""
    side = "left" if end_y > 0 else "right" if end_y < 0 else ""
    return "-".join(w for w in (along, side) if w)


_GRIDS = ((("u", "i", "o"), ("j", "k", "l"), ("m", ",", ".")),
          (("U", "I", "O"), ("J", "K", "L"), ("M", "<", ">")))


def key_help() -> str:
    """The key map as a block of text (for --help and README), made from the bindings."""
    lines = []
    for grid, note in zip(_GRIDS, ("turning", "Shift: strafing, no turn"), strict=True):
        for k, row in enumerate(grid):
            keys = "    ".join(row)
            where = "".join(f"{key_direction(key):<15}" for key in row).rstrip()
            tail = f"   ({note})" if k == 0 else ""
            lines.append(f"   {keys}     {where}{tail}")
    lines += [
        "arrow keys: up i, down ',', left j, right l",
        "q/z  all speeds +/-10 %     w/x  linear only     e/c  angular only",
        "space or k  stop      r  recover after a fault      Esc or Ctrl-C  quit",
    ]
    return "\n".join(lines)


@dataclass
class TeleopModel:
    """Speeds, direction and input freshness of one manual front end.

    ``speed`` m/s and ``turn`` rad/s scale the direction multipliers and stay within
    ``max_speed`` / ``max_turn``; ``timeout_s`` (0: never) zeroes the command when no
    input arrived for that long. Times are ``time.monotonic()`` seconds."""

    speed: float
    turn: float
    max_speed: float
    max_turn: float
    timeout_s: float
    direction: Direction = (0.0, 0.0, 0.0)
    last_input_at: float = -math.inf
    last_input: str = ""  # the last key (or a front end's label for its input)
    recover_requested: bool = False
    quit_requested: bool = False

    def __post_init__(self) -> None:
        for name in ("speed", "turn", "max_speed", "max_turn"):
            value = getattr(self, name)
            if not value > 0:  # also refuses NaN; inf is a valid maximum
                raise ValueError(f"{name} must be positive, got {value!r}")
        if not (self.timeout_s >= 0 and math.isfinite(self.timeout_s)):
            raise ValueError(f"timeout_s must be 0 or more seconds, got {self.timeout_s!r}")
        self.speed = min(self.speed, self.max_speed)
        self.turn = min(self.turn, self.max_turn)

    @classmethod
    def for_config(cls, cfg: ChassisConfig, speed: float, turn: float,
                   timeout_s: float) -> TeleopModel:
        """A model whose maxima are what ``cfg``'s base can reach (:func:`speed_limits`)."""
        max_speed, max_turn = speed_limits(cfg)
        return cls(speed, turn, max_speed, max_turn, timeout_s)

    # ------------------------------------------------------------ input

    def _seen(self, now: float, label: str) -> None:
        self.last_input_at, self.last_input = now, label

    def move(self, direction: Direction, now: float, label: str = "") -> None:
        """Move towards ``direction`` (each multiplier clipped to [-1, 1], so a stick's
        values may be passed as they are) until the input stops."""
        x, y, th = (max(-1.0, min(1.0, float(v))) if math.isfinite(v) else 0.0
                    for v in direction)
        self.direction = (x, y, th)
        self._seen(now, label)

    def scale(self, linear: float, angular: float, now: float, label: str = "") -> None:
        """Multiply the speeds (within their maxima)."""
        if not (linear > 0 and angular > 0):
            raise ValueError(f"speed factors must be positive, got {linear}, {angular}")
        self.speed = min(self.speed * linear, self.max_speed)
        self.turn = min(self.turn * angular, self.max_turn)
        self._seen(now, label)

    def stop(self, now: float, label: str = "") -> None:
        """Stand still (the front end is alive and asks for no motion)."""
        self.direction = (0.0, 0.0, 0.0)
        self._seen(now, label)

    def release(self) -> None:
        """The deadman was let go: no motion until the next input."""
        self.direction = (0.0, 0.0, 0.0)
        self.last_input_at = -math.inf

    def press(self, key: str, now: float) -> KeyAction:
        """Apply one key; returns what it asked for."""
        action = key_action(key)
        if action.intent is Intent.MOVE:
            self.move(action.direction, now, key)
        elif action.intent is Intent.SPEED:
            self.scale(*action.factors, now, key)
        elif action.intent is Intent.RECOVER:
            self.recover_requested = True
            self._seen(now, key)
        elif action.intent is Intent.QUIT:
            self.quit_requested = True
            self.stop(now, key)
        else:
            self.stop(now, key)
        return action

    def take_recover(self) -> bool:
        """True once per recover request (the front end then calls ``Chassis.recover``)."""
        wanted, self.recover_requested = self.recover_requested, False
        return wanted

    # ------------------------------------------------------------ output

    def expired(self, now: float) -> bool:
        """No input for ``timeout_s`` (never, with a timeout of 0)."""
        return self.timeout_s > 0 and now - self.last_input_at > self.timeout_s

    def command(self, now: float) -> Twist:
        """The twist to command now: zero once the input expired."""
        if self.expired(now):
            self.direction = (0.0, 0.0, 0.0)
        x, y, th = self.direction
        return Twist(x * self.speed, y * self.speed, th * self.turn)
