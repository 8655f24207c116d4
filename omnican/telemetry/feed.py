"""The one feed of a base's telemetry: the control loop offers a snapshot at the state
rate (in the base's clock: the feed is the base's snapshot sink, attached from above by
:func:`omnican.telemetry.attach.feed_of`) and the frames go into a tap; every front end
that subscribes (the ROS 2 bridge, the live view, an MCAP recording) gets the same
messages of each sample, built once by :class:`~omnican.telemetry.model.Telemetry`.

In real time the messages are built and handed to the front ends on one thread of the
feed's own (``omnican-telemetry``): offering a sample costs the loop a queue append. A
front end that falls behind costs samples (counted in :attr:`Feed.dropped`), never a
late cycle. In lock-step (a :class:`~omnican.clock.SimClock`) it all happens inside the
offer, on the clock's thread: every sample of a ``--fast`` run reaches every front end,
stamped with the simulated time, and the run is the same every time.
"""

from __future__ import annotations

import collections
import logging
import threading
from collections.abc import Callable
from typing import Any, Protocol

from omnican.chassis.state import Snapshot
from omnican.clock import Clock
from omnican.core.kinematics import OmniKinematics
from omnican.telemetry.frames import FrameMessages, FrameTap
from omnican.telemetry.messages import TelemetrySample
from omnican.telemetry.model import Message, Telemetry
from omnican.telemetry.settings import TelemetrySettings

logger = logging.getLogger("omnican.telemetry")

QUEUE_SAMPLES = 250  # 5 s at 50 Hz: a front end slower than that loses the oldest
WAKE_S = 0.2  # the longest frames wait with no sample coming (a stopped base, no base)


class Sink(Protocol):
    """A front end fed by the telemetry (called on the feed's thread)."""

    def wants(self, topic: str) -> bool:
        """Whether it publishes ``topic`` now (a live view: whether anyone watches)."""
        ...

    def publish(self, messages: list[Message]) -> None:
        """The messages of one sample (and the frames before it), on its topics."""
        ...


class Feed:
    """See the module docstring. ``make_database``: the base's DBC, for the decoded
    frames (made on first need)."""

    def __init__(self, settings: TelemetrySettings, kinematics: OmniKinematics, clock: Clock,
                 make_database: Callable[[], Any] | None = None, has_base: bool = True) -> None:
        self.settings = settings
        self.has_base = has_base  # False: a simulator's truth alone, no base's state
        self.clock = clock
        self.model = Telemetry(settings, kinematics)
        self.frames = FrameTap()
        self.frame_messages = FrameMessages(settings.channel, make_database)
        #: a simulated base whose ground truth goes along with each sample
        self.truth: Any = None
        #: told True when the first front end subscribes, False when the last one leaves
        self.on_active: Callable[[bool], None] | None = None
        self.dropped = 0  # samples a front end was too slow for
        self._sinks: tuple[Sink, ...] = ()
        self._lock = threading.Lock()
        # Held while samples are handed to the front ends: remove() waits on it, so that
        # a front end that left gets nothing more (the ROS 2 bridge closes its DDS writers
        # next: a sample handed to it then failed in a traceback). Re-entrant: a front end
        # may leave from inside its own publish.
        self._handing = threading.RLock()
        self._lockstep = clock.lockstep
        self._pending: collections.deque[tuple[Snapshot | None, int]] = collections.deque()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False

    # ------------------------------------------------------------ front ends

    def add(self, sink: Sink) -> None:
        """Send ``sink`` every sample from now on."""
        with self._lock:
            if self._closed:
                raise RuntimeError("the telemetry feed is closed")
            first = not self._sinks
            self._sinks += (sink,)
            if first and not self._lockstep and self._thread is None:
                self._thread = threading.Thread(target=self._run, name="omnican-telemetry",
                                                daemon=True)
                self._thread.start()
        if first and self.on_active is not None:
            self.on_active(True)

    def remove(self, sink: Sink) -> None:
        """Send ``sink`` nothing more: when this returns, no sample is being handed to it
        (one under way is waited for)."""
        with self._lock:
            self._sinks = tuple(s for s in self._sinks if s is not sink)
            last = not self._sinks
        with self._handing:
            pass
        if last and self.on_active is not None:
            self.on_active(False)

    @property
    def active(self) -> bool:
        return bool(self._sinks)

    def wants(self, topic: str) -> bool:
        """Whether any front end publishes ``topic`` now."""
        return any(s.wants(topic) for s in self._sinks)

    # ------------------------------------------------------------ samples

    def offer(self, snapshot: Snapshot | None) -> None:
        """A sample of the base, now (the loop thread; ``None``: the truth alone)."""
        stamp_ns = round(self.clock.wall() * 1e9)
        if self._lockstep:
            self._publish(snapshot, stamp_ns)
            return
        pending = self._pending
        if len(pending) >= QUEUE_SAMPLES:
            pending.popleft()
            self.dropped += 1
        pending.append((snapshot, stamp_ns))
        if not self._wake.is_set():
            self._wake.set()

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(WAKE_S)
            self._wake.clear()
            self._drain()

    def _drain(self, last: Snapshot | None = None) -> None:
        pending = self._pending
        while pending:
            snapshot, ns = pending.popleft()
            self._publish(snapshot, ns)
        if last is not None:
            self._publish(last, round(self.clock.wall() * 1e9), last=True)
        elif self.frames.queue:
            self._publish(None, None)  # frames with no sample to go with (none coming)

    def _publish(self, snapshot: Snapshot | None, stamp_ns: int | None,
                 last: bool = False) -> None:
        if not self._sinks:
            self.frames.queue.clear()
            return
        try:
            out = self.frame_messages.messages(self.frames.take(), self.wants)
            if stamp_ns is not None:
                out += self.model.messages(self._sample(snapshot, stamp_ns), self.wants, last)
        except Exception:  # a bad sample must not end the telemetry
            logger.exception("telemetry: building messages failed")
            return
        if not out:
            return
        with self._handing:
            for sink in self._sinks:  # read under the lock: none that left since
                try:
                    sink.publish([msg for msg in out if sink.wants(msg.topic)])
                except Exception:  # a front end must never take the others (or the robot) down
                    logger.exception("telemetry: %s failed to publish", type(sink).__name__)

    def _sample(self, snapshot: Snapshot | None, stamp_ns: int) -> TelemetrySample:
        truth = self.truth
        true_pose = truth.true_pose if truth is not None else None
        true_twist = truth.true_twist if truth is not None else None
        if snapshot is None:
            return TelemetrySample(stamp_ns, None, None, None, (), None, true_pose, true_twist)
        return TelemetrySample(stamp_ns, snapshot.pose, snapshot.twist, snapshot.command,
                               snapshot.wheels, snapshot.status, true_pose, true_twist,
                               snapshot.fused)

    # ------------------------------------------------------------ closing

    def close(self, last: Snapshot | None = None) -> None:
        """Hand the front ends what is queued, and ``last`` (the final sample: its
        diagnostics go whether due or not); then no more. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        thread = self._thread
        if thread is not None:
            self._stop.set()
            self._wake.set()
            thread.join(timeout=5.0)
        self._drain(last)
        with self._lock:
            self._sinks = ()
        if self.dropped or self.frames.dropped:
            logger.warning("telemetry dropped %d samples and %d frames (a front end fell "
                           "behind)", self.dropped, self.frames.dropped)
