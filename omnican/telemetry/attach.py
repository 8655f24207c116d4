"""How the telemetry attaches from above: to a base (:func:`feed_of`), or to a simulator
with no base (:func:`simulator_feed`, ``omnican sim --foxglove``). Neither knows of it:
a base offers its snapshots to one sink (:mod:`omnican.chassis.sink`) and its frames to
listeners; a simulator runs a tick on its clock and hears its drives' frames. A base
that runs beside a simulator carries the simulator's ground truth in its telemetry
(:func:`add_truth`, the one place it is wired): every front end shows it as it is.

The DBC attaches here too: the feed decodes frames with the base's DBC (cantools,
imported when a front end first wants decoded frames).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any, Protocol

from omnican.clock import Clock
from omnican.config import ChassisConfig
from omnican.core.kinematics import OmniKinematics, Twist
from omnican.core.odometry import Pose2D

if TYPE_CHECKING:
    from omnican.chassis.base import Chassis
    from omnican.chassis.state import Snapshot
    from omnican.telemetry.feed import Feed


def feed_of(base: Chassis) -> Feed:
    """The one feed of ``base``'s telemetry, attached on first use: every front end
    (the ROS 2 bridge, the live view, an MCAP recording) asks for it here and gets the
    same feed; it is closed with the base (its last sample: the base's last snapshot).
    Raises RuntimeError once the base is closed."""
    return base.attachments.setdefault(_FEED, lambda: _base_feed(base))


def add_truth(base: Chassis, sim: Simulator | None) -> None:
    """The simulator ``sim`` (None: none) that ``base`` runs against: its ground truth
    goes with every sample of the base's telemetry from now on (``/sim/true_pose`` and
    ``/sim/pose2d`` of every front end, of a recording). The one place the truth is
    wired, by whoever runs a base beside a simulator (the command line's session), before
    the front ends attach; no front end wires it."""
    if sim is None:
        return
    # Kept for the feed until one is made (by the first front end or recording that
    # asks: a base none asks for makes none, nor imports the telemetry).
    kept = base.attachments.get(_TRUTH)
    if kept is None:
        base.attachments.add(_TRUTH, _Truth(sim))
    else:
        kept.sim = sim
    feed = base.attachments.get(_FEED)
    if feed is not None:  # made already
        feed.truth = sim


_FEED, _TRUTH = "telemetry", "truth"


class _Truth:
    """The simulator a base runs beside, for its feed (an attachment: nothing to close)."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim

    def close(self, last: Snapshot | None = None) -> None:
        pass


def _base_feed(base: Chassis) -> Feed:
    from omnican.telemetry.feed import Feed
    from omnican.telemetry.settings import TelemetrySettings

    cfg, bus = base.cfg, base.bus
    feed = Feed(TelemetrySettings.from_config(cfg), cfg.kinematics(), base.clock,
                make_database=_database(cfg))
    kept = base.attachments.get(_TRUTH)
    if kept is not None:
        feed.truth = kept.sim
    every = max(1, round(cfg.chassis.rate_hz / feed.settings.state_rate_hz))

    def active(on: bool) -> None:
        """A first front end subscribed (the frames go to the feed too, and samples at
        the state rate), or the last one left."""
        if on:
            bus.add_listener(feed.frames, sent=True)
            base.offer_snapshots(feed, every)
        else:
            base.offer_snapshots(None)
            bus.remove_listener(feed.frames)

    feed.on_active = active
    return feed


class Simulator(Protocol):
    """What :func:`simulator_feed` reads of a simulated base
    (:class:`omnican.sim.SimulatedBase`)."""

    cfg: ChassisConfig
    clock: Clock
    true_kinematics: OmniKinematics
    scheduler: Any  # add(fn(now)) / remove(fn), every period_s of the clock
    network: Any  # its notifier (None in lock-step) hears the drives' frames

    @property
    def true_pose(self) -> Pose2D: ...

    @property
    def true_twist(self) -> Twist: ...


@contextlib.contextmanager
def simulator_feed(sim: Simulator) -> Iterator[Feed]:
    """A simulator's own telemetry, for a front end without a base (``omnican sim
    --foxglove``): its ground truth at the state rate of its clock, and the frames its
    drives hear; closed when the block ends."""
    from omnican.telemetry.feed import Feed
    from omnican.telemetry.settings import TelemetrySettings

    cfg = sim.cfg
    feed = Feed(TelemetrySettings.from_config(cfg), sim.true_kinematics, sim.clock,
                make_database=_database(cfg), has_base=False)
    feed.truth = sim
    every = max(1, round(1.0 / (sim.scheduler.period_s * feed.settings.state_rate_hz)))
    ticks = [0]

    def tick(now: float) -> None:
        ticks[0] += 1
        if feed.active and not ticks[0] % every:
            feed.offer(None)

    sim.scheduler.add(tick)
    notifier = sim.network.notifier

    def frames_while_watched(active: bool) -> None:
        # Frames queue only while a front end takes them: with none attached they
        # filled the queue and, on quit, read as one that fell behind.
        if notifier is None:
            return
        if active:
            notifier.add_listener(feed.frames)
        else:
            with contextlib.suppress(ValueError):
                notifier.remove_listener(feed.frames)
            feed.frames.queue.clear()

    feed.on_active = frames_while_watched
    try:
        yield feed
    finally:
        sim.scheduler.remove(tick)
        frames_while_watched(False)
        feed.close()


def _database(cfg: ChassisConfig) -> Callable[[], Any]:
    """What makes the base's DBC, for decoded frames (cantools: imported when a front end
    wants them)."""

    def make() -> Any:
        from omnican.plan.dbc import database_for

        return database_for(cfg)

    return make
