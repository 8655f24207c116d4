"""Recordings by file name: :func:`open_recording` picks the recorder by the file's
extension (a python-can log, :class:`~omnican.record.can_log.LogRecorder`: the frames;
``.mcap``, :class:`~omnican.record.mcap.McapRecorder`: the frames and the robot's state,
a telemetry sink); :class:`FileRecording` records a base from its first frame on
(``Chassis.open(cfg, record=FileRecording(path))``); :func:`recording_frames` records a
bus a front end listens to itself (``omnican monitor``).
"""

from __future__ import annotations

import contextlib
import importlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can

from omnican.chassis.state import Snapshot
from omnican.config import ChassisConfig
from omnican.io.bus import Recorder
from omnican.record.can_log import LogRecorder
from omnican.telemetry.attach import feed_of
from omnican.telemetry.feed import Feed

if TYPE_CHECKING:
    from omnican.chassis.base import Chassis

#: Recording formats that are front ends of their own (extension -> "module:Class"):
#: made by name, imported only when one is made.
FRONT_END_RECORDERS = {".mcap": "omnican.record.mcap:McapRecorder"}


def open_recording(path: str | Path, cfg: ChassisConfig | None = None) -> Any:
    """The recorder for ``path``'s format: an MCAP recording (frames and the robot's
    state: a telemetry sink; ``cfg``'s DBC goes along) or a :class:`LogRecorder`
    (frames, any python-can format). Raises ConfigError for a path it cannot write."""
    path = Path(path)
    target = FRONT_END_RECORDERS.get(path.suffix.lower())
    if target is not None:
        module, _, name = target.partition(":")
        return getattr(importlib.import_module(module), name)(path, cfg)
    return LogRecorder(path)


def records_state(recorder: Any) -> bool:
    """Whether ``recorder`` records the robot's state too (a telemetry sink), not only
    the frames."""
    return hasattr(recorder, "publish")


class FileRecording:
    """A recording of a base to ``path``, in the format of its extension (see
    :func:`open_recording`), for ``Chassis.open(cfg, record=FileRecording(path))``
    (a :class:`omnican.chassis.sink.Recording`): the base opens the file once its config
    passed the checks, so a base that cannot be made writes none, records from the
    bus's first frame on (the configuration too) and closes it with itself. A log
    file takes the frames from the bus; an MCAP file takes them, and the robot's state,
    from the base's telemetry."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        #: what :meth:`open` made: a LogRecorder or an MCAP recorder (None before)
        self.recorder: Any = None
        self._feed: Feed | None = None

    def open(self, cfg: ChassisConfig) -> Recorder | None:
        self.recorder = recorder = open_recording(self.path, cfg)
        return None if records_state(recorder) else recorder

    def attach(self, base: Chassis) -> None:
        if records_state(self.recorder):
            self._feed = feed = feed_of(base)
            feed.add(self.recorder)

    def close(self, last: Snapshot | None = None) -> None:
        """Close the file (the telemetry's last sample is in it: the feed closes first),
        saying in an MCAP file's metadata what did not reach it. A log file is closed
        by the bus it was handed to, after its last frame; here only when the base
        could not be opened (``last`` None). Idempotent."""
        recorder = self.recorder
        if recorder is None:
            return
        if records_state(recorder):
            feed = self._feed
            recorder.close(dropped_frames=feed.frames.dropped if feed is not None else 0)
        elif last is None:
            recorder.close()


@contextlib.contextmanager
def recording_frames(path: str | Path, cfg: ChassisConfig) -> Iterator[can.Listener]:
    """A listener that records the frames it is handed to ``path`` (any format
    :func:`open_recording` takes), for a front end that listens to a bus of its own
    (``omnican monitor``); closed, with the file, when the block ends."""
    recorder = open_recording(path, cfg)
    if not records_state(recorder):
        try:
            yield recorder
        finally:
            recorder.close()
        return
    from omnican.clock import REAL_TIME
    from omnican.plan.dbc import database_for
    from omnican.telemetry import TelemetrySettings

    feed = Feed(TelemetrySettings.from_config(cfg), cfg.kinematics(), REAL_TIME,
                make_database=lambda: database_for(cfg), has_base=False)
    try:
        feed.add(recorder)
        yield feed.frames
    finally:
        feed.close()
        recorder.close()
