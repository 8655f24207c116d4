"""Who may command the base when more than one source could: one at a time, and who may
do what else (:mod:`omnican.chassis.actions`: the one table, :data:`RULES`).

A source (the terminal's keys, a gamepad, ROS 2 ``cmd_vel``, a Foxglove client) asks
before each command. The first to ask holds control until it releases it (it left, or
its keys went idle) or sends nothing for ``timeout_s`` (the chassis watchdog's timeout:
by then the base has stopped by itself). Until then every other source is refused and
told who holds it.

A stop is not a command: anyone may stop the base at any time. A stop by another source
also takes control from the one driving, which is then refused until it lets go (sends
nothing for ``timeout_s``): a Teleop button held down does not start the base again the
moment after someone else stopped it. The rest (recover, reset the odometry, change a
limit, the simulator's console) is the driver's, or anyone's while no one drives.

A front end does not apply these rules itself: it asks the base for a
:class:`CommandSource` (:meth:`omnican.chassis.Chassis.command_source`), one per source,
and drives, stops, halts, recovers, resets the pose and changes limits through it; each
action returns its :class:`~omnican.chassis.actions.Outcome` (done, refused by whom, or
failed) that the front end only words. Every source of one base shares the base's one
arbiter, so a new front end shares control with the others by construction. The arbiter
lives here, in the chassis layer, so that the base may hand it out (the layers above may
not be imported from here).

Pure: no I/O, no threads of its own; safe to call from any thread.
"""

from __future__ import annotations

import math
import threading
import warnings
from collections.abc import Callable
from typing import Protocol

from omnican.chassis.actions import Action, Outcome, refuser
from omnican.core.kinematics import Twist
from omnican.core.odometry import Pose2D
from omnican.errors import OmnicanError


class CommandArbiter:
    """One controller at a time (see the module docstring). Times are seconds on the
    caller's clock (``time.monotonic()`` in real time)."""

    def __init__(self, timeout_s: float) -> None:
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s must be a positive number, got {timeout_s!r}")
        self.timeout_s = float(timeout_s)
        self._lock = threading.Lock()
        self._holder: str | None = None
        self._last = -math.inf
        self._stopped: dict[str, tuple[str, float]] = {}  # source -> (by whom, last heard)
        self._acting: dict[str, int] = {}  # source -> its actions under way (see perform)

    def claim(self, source: str, now: float, send: Callable[[], None] | None = None
              ) -> Outcome:
        """``source`` wants to command at ``now`` (:attr:`Action.DRIVE`): done
        (:attr:`Outcome.ok`) if it may, and it holds control from here on (``send``, the
        command, runs before anyone can take control away); else refused by the source
        that holds control, or that stopped this one (:attr:`Outcome.refused_by`). A
        command the base refuses (``send`` raises, e.g. ValueError for a value beyond
        sense) takes no control: the error goes to the caller, nothing else changes."""
        with self._lock:
            stopped = self._stopped.get(source)
            if stopped is not None:
                if now - stopped[1] <= self.timeout_s:
                    self._stopped[source] = (stopped[0], now)  # still pressing: still out
                    return Outcome(Action.DRIVE, source, refused_by=stopped[0])
                del self._stopped[source]  # it let go
            holder = refuser(Action.DRIVE, source, self._current(now))
            if holder is not None:
                return Outcome(Action.DRIVE, source, refused_by=holder)
            if send is not None:
                send()
            self._holder, self._last = source, now
            return Outcome(Action.DRIVE, source)

    def ask(self, source: str, action: Action, now: float) -> Outcome:
        """Whether ``source`` may take ``action`` at ``now``, by the table
        (:data:`~omnican.chassis.actions.RULES`) and who then drives. Asks only: takes
        no control, does nothing."""
        with self._lock:
            return Outcome(action, source, refused_by=refuser(action, source,
                                                             self._current(now)))

    def decide(self, source: str, action: Action, now: float,
               run: Callable[[], None] | None = None) -> Outcome:
        """``source`` takes ``action`` at ``now`` if the table lets it (:meth:`ask`):
        ``run`` (quick: a stop, a halt) then runs here, with no command granted in
        between, and a stop by another than the driver takes control from it, which is
        refused until it has sent nothing for ``timeout_s`` (:attr:`Outcome.took_from`).
        A ``run`` that raises changes nothing here. A command is :meth:`claim`'s (it
        takes control)."""
        if action is Action.DRIVE:
            raise ValueError("a command goes through claim(), which takes control")
        with self._lock:
            holder = self._current(now)
            refused = refuser(action, source, holder)
            if refused is not None:
                return Outcome(action, source, refused_by=refused)
            if run is not None:
                run()
            if not action.stops or holder is None or holder == source:
                return Outcome(action, source)
            self._holder, self._last = None, -math.inf
            self._stopped[holder] = (source, now)
            return Outcome(action, source, took_from=holder)

    def perform(self, source: str, action: Action, now: float, do: Callable[[], object],
                ended: Callable[[], float]) -> Outcome:
        """``source`` takes ``action`` (not a command, not a stop) at ``now`` if the table
        lets it (:meth:`ask`), and ``do`` runs outside the lock (a recover waits seconds
        for the drives), with ``source`` holding control until it returns: another's
        command is refused by ``source`` meanwhile, as if ``source`` drove, so no one
        starts driving while it acts (anyone may still stop: that takes control from it,
        as from a driver). Afterwards control is as it was: ``source`` keeps it (from
        ``ended()``, the time then) if it held it before, else no one holds it. What
        ``do`` raises goes to the caller, control restored the same way."""
        if action is Action.DRIVE or action.stops:
            raise ValueError(f"{action.value!r} has its own method (claim, decide)")
        with self._lock:
            holder = self._current(now)
            refused = refuser(action, source, holder)
            if refused is not None:
                return Outcome(action, source, refused_by=refused)
            self._holder = source  # no lapse while it acts (_current)
            self._acting[source] = self._acting.get(source, 0) + 1
        try:
            do()
        finally:
            with self._lock:
                left = self._acting[source] - 1
                if left:
                    self._acting[source] = left
                else:
                    del self._acting[source]
                if not left and self._holder == source:  # (a stop meanwhile took it)
                    if holder == source:
                        self._last = ended()
                    else:
                        self._holder, self._last = None, -math.inf
        return Outcome(action, source)

    def stop_by(self, source: str, now: float, stop: Callable[[], None] | None = None
                ) -> str | None:
        """``source`` stops the base at ``now`` (``stop`` runs with no command granted in
        between): if another source drives, it loses control and is refused until it has
        sent nothing for ``timeout_s``. Returns that source, if any (anyone may stop:
        :meth:`decide` never refuses it)."""
        return self.decide(source, Action.STOP, now, stop).took_from

    def stopped_by(self, source: str, now: float) -> str | None:
        """Who stopped ``source``, while it is still refused for that."""
        with self._lock:
            stopped = self._stopped.get(source)
            return stopped[0] if stopped and now - stopped[1] <= self.timeout_s else None

    def release(self, source: str, now: float, stop: Callable[[], None] | None = None
                ) -> bool:
        """``source`` gives control up at ``now`` (it left); True if it held control then
        (not if its hold had lapsed). ``stop`` runs only then, before anyone else can
        take control (so it stops this source's motion, never another's)."""
        with self._lock:
            if self._current(now) != source:
                return False
            if stop is not None:
                stop()
            self._holder, self._last = None, -math.inf
            return True

    def holder(self, now: float) -> str | None:
        """Who holds control at ``now`` (None: no one)."""
        with self._lock:
            return self._current(now)

    def _current(self, now: float) -> str | None:
        holder = self._holder
        if holder is not None and now - self._last > self.timeout_s and \
                holder not in self._acting:
            self._holder = None  # silent for the timeout: the base stopped by itself
        return self._holder


class _Clock(Protocol):
    def now(self) -> float: ...


class Commandable(Protocol):
    """What a :class:`CommandSource` acts on: a :class:`~omnican.chassis.Chassis`, or a
    stand-in in a test (which needs only what its test calls)."""

    @property
    def clock(self) -> _Clock: ...

    def set_twist(self, twist: Twist) -> None: ...

    def stop(self) -> None: ...

    def halt(self, reason: str) -> None: ...

    def recover(self) -> None: ...

    def reset_pose(self, pose: Pose2D | None = None) -> None: ...

    def set_limits(self, **changes: float) -> object: ...


#: What the base's actions raise when it refuses or fails one (a drive it cannot enable,
#: a pose or a limit beyond sense, a closed base): told in the answer, not raised.
_REFUSALS = (OmnicanError, ValueError)


class CommandSource:
    """One source of commands for a base (the terminal's keys, a ROS 2 publisher, a
    Foxglove client), named as the others are told of it: every command, stop and other
    action goes through the base's :class:`CommandArbiter`, at the base's clock, which
    answers it by the one table (:mod:`omnican.chassis.actions`). Ask the base for it
    (:meth:`omnican.chassis.Chassis.command_source`); cheap to make, one per source name
    (two of one name are one source). Safe to call from any thread."""

    __slots__ = ("_arbiter", "_base", "name")

    def __init__(self, base: Commandable, arbiter: CommandArbiter, name: str) -> None:
        self.name = name
        self._base = base
        self._arbiter = arbiter

    @property
    def timeout_s(self) -> float:
        """How long a silent holder keeps control (the chassis watchdog's timeout)."""
        return self._arbiter.timeout_s

    def drive(self, twist: Twist) -> Outcome:
        """Command the base to ``twist`` (body frame: m/s, m/s, rad/s), if this source may
        (it then holds control): done (:attr:`Outcome.ok`) if sent, else refused by the
        source that holds control, or that stopped this one (:attr:`Outcome.refused_by`;
        :meth:`stopped_by` tells which), and nothing is sent. A twist the base refuses
        (ValueError: NaN, beyond sense) raises and takes no control. A zero twist is a
        command like any other: it holds control too."""
        base = self._base
        return self._arbiter.claim(self.name, base.clock.now(), lambda: base.set_twist(twist))

    def send(self, twist: Twist) -> str | None:
        """Deprecated (goes in the next release): :meth:`drive`, whose answer is an
        :class:`~omnican.chassis.actions.Outcome`. None if sent, else the refuser."""
        warnings.warn("CommandSource.send() moved to CommandSource.drive(), which returns "
                      "an Outcome; the old name goes in the next release",
                      DeprecationWarning, stacklevel=2)
        return self.drive(twist).refused_by

    def stop(self) -> str | None:
        """Stop the base now, whoever drives (anyone may). If another source drove, it
        loses control until it lets go: returns that source (None: none did)."""
        base = self._base
        return self._arbiter.stop_by(self.name, base.clock.now(), base.stop)

    def halt(self, reason: str) -> Outcome:
        """Stop the base and hold it stopped until a recover, whoever drives (anyone
        may), with ``reason`` as the stop's reason (:meth:`omnican.chassis.Chassis.halt`).
        If another source drove, it loses control until it lets go
        (:attr:`Outcome.took_from`). Failed: a closed base."""
        base = self._base
        try:
            return self._arbiter.decide(self.name, Action.HALT, base.clock.now(),
                                        lambda: base.halt(reason))
        except _REFUSALS as exc:
            return Outcome(Action.HALT, self.name, failed=str(exc))

    def recover(self) -> Outcome:
        """Clear a latched stop (:meth:`omnican.chassis.Chassis.recover`; bounded, it
        waits for the drives), if this source may: refused while another drives."""
        return self.act(Action.RECOVER, self._base.recover)

    def reset_pose(self, pose: Pose2D | None = None) -> Outcome:
        """Set the odometry pose (default: the origin), if this source may: refused while
        another drives; failed for a pose beyond sense."""
        base = self._base
        return self.act(Action.RESET_POSE, lambda: base.reset_pose(pose))

    def set_limits(self, **changes: float) -> Outcome:
        """Change live limits (:meth:`omnican.chassis.Chassis.set_limits`), if this
        source may: refused while another drives; failed for a value the config's checks
        refuse (nothing changes then)."""
        base = self._base
        return self.act(Action.SET_LIMITS, lambda: base.set_limits(**changes))

    def act(self, action: Action, do: Callable[[], object]) -> Outcome:
        """Run ``do`` for ``action`` if the table lets this source take it now (the
        simulator's console, which the base does not know; the base's own actions have
        their methods). ``do`` runs outside the arbiter (a recover takes seconds) with
        this source holding control meanwhile: no other source starts driving under it
        (:meth:`CommandArbiter.perform`). What ``do`` raises as a refusal or failure
        (OmnicanError, ValueError) is the outcome's :attr:`~Outcome.failed`."""
        if action is Action.DRIVE or action.stops:
            raise ValueError(f"{action.value!r} has its own method (send, stop, halt)")
        clock = self._base.clock
        try:
            return self._arbiter.perform(self.name, action, clock.now(), do, clock.now)
        except _REFUSALS as exc:
            return Outcome(action, self.name, failed=str(exc))

    def may(self, action: Action) -> Outcome:
        """Whether this source may take ``action`` now, by the table; asks only (takes no
        control, does nothing). A source that another's stop keeps out may be told it may
        drive: :meth:`send` refuses it (it is out until it lets go)."""
        return self._arbiter.ask(self.name, action, self._base.clock.now())

    def release(self, stop: bool = False) -> bool:
        """Give control up (this source left, or went idle): True if it held control.
        With ``stop``, the base stops then too (only if this source drove it)."""
        base = self._base
        return self._arbiter.release(self.name, base.clock.now(),
                                     base.stop if stop else None)

    def holder(self) -> str | None:
        """Who holds control now (None: no one; it may be this source)."""
        return self._arbiter.holder(self._base.clock.now())

    def may_act(self) -> str | None:
        """Deprecated (goes in the next release): ``may(Action.RECOVER)``, whose answer
        is an :class:`~omnican.chassis.actions.Outcome`. None if it may, else who drives."""
        warnings.warn("CommandSource.may_act() moved to CommandSource.may(Action.RECOVER), "
                      "which returns an Outcome; the old name goes in the next release",
                      DeprecationWarning, stacklevel=2)
        return self.may(Action.RECOVER).refused_by

    def stopped_by(self) -> str | None:
        """Who stopped this source, while it is still refused for that (None: no one)."""
        return self._arbiter.stopped_by(self.name, self._base.clock.now())

    def __repr__(self) -> str:
        return f"CommandSource({self.name!r})"
