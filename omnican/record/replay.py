"""Decode a recording of the bus into time series, offline (no bus, no threads).

What is on the wire is worked out from the config alone (:func:`omnican.plan.node.node_layouts`):
the cyclic RPDOs carry each wheel's target velocity, the SYNC TPDOs each wheel's
position, the event TPDOs each state machine's statusword, each PDO unpacked by its
:class:`omnican.plan.codec.PdoCodec` as the control loop unpacks it. :func:`decode` follows
the frames in time order and applies the chassis' rules:

* position samples belong to the latest SYNC before them; odometry integrates only
  complete sets (every wheel answered that SYNC), as :class:`omnican.chassis.Chassis`;
* counters are folded into continuous counts across wrap-around, and a drive's
  boot-up (a reboot) restarts the fold without a jump, by the loop's own
  :class:`omnican.core.wheel_odometry.WheelOdometry`.

:func:`read_frames` (:mod:`omnican.record.read`, re-exported here) is the only I/O: it
reads any python-can log format by extension, and ``.mcap``, and what it can of a
recording cut short or damaged, with one warning (:func:`cut_note`).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from omnican.config import ChassisConfig
from omnican.core.odometry import Odometry
from omnican.core.wheel_odometry import (
    SPEED_WINDOW_S,
    CounterSampleSlot,
    EncoderCounters,
    WheelOdometry,
)
from omnican.errors import RecordingError  # noqa: F401 (what a reader raises, named here too)
from omnican.plan.codec import PdoCodec
from omnican.plan.health_fields import HEALTH_FIELDS
from omnican.plan.node import NodeLayout, node_layouts
from omnican.protocol.cia301 import (
    EMCY_BASE,
    HEARTBEAT_BASE,
    NMT_COB_ID,
    NMT_RESETS,
    NMT_STATE_MASK,
    SYNC_COB_ID,
    NmtState,
)
from omnican.protocol.cia402 import State, decode_state, describe_emcy
from omnican.protocol.object_map import Entry, Obj
from omnican.protocol.sdo_cycle import SDO_ANSWER_BASE, AnswerKind, parse_answer
from omnican.record.read import read_frames, read_recording  # noqa: F401 (read_frames: here too)

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]


class Frame(Protocol):
    """What decoding needs of a frame (a :class:`can.Message` fits)."""

    @property
    def timestamp(self) -> float: ...

    @property
    def arbitration_id(self) -> int: ...

    @property
    def data(self) -> bytes | bytearray: ...


@dataclass(frozen=True)
class StateChange:
    """A stage entered ``state`` (``t`` in s from the first frame; ``statusword`` is
    the first one that showed it)."""

    t: float
    state: State
    statusword: int


@dataclass(frozen=True)
class StageTrack:
    """One CiA 402 state machine (a controlword/statusword pair) and its history."""

    node_id: int
    wheels: tuple[int, ...]
    label: str
    changes: tuple[StateChange, ...]


@dataclass(frozen=True)
class EmcyEvent:
    t: float
    node_id: int
    code: int
    register: int

    @property
    def text(self) -> str:
        return "error reset" if self.code == 0 else describe_emcy(self.code)


_TPDO_BASES = (0x180, 0x280, 0x380, 0x480)  # the COB-IDs of TPDO1-4, less the node id


@dataclass(frozen=True)
class Replay:
    """A decoded recording. Times are seconds from the first frame; speeds m/s at the
    rim; travel m; poses (x m, y m, theta rad, continuous) in the start pose's frame.

    ``sync_t``, ``counts``, ``travel``, ``actual_speed`` and ``poses`` have one row per
    complete SYNC set (what the odometry integrated); the first row only seeds."""

    start_time: float  # wall-clock time of the first frame
    duration: float
    frames: int
    wheel_names: tuple[str, ...]
    target_t: tuple[FloatArray, ...]  # per wheel: when each cyclic target was sent
    target_speed: tuple[FloatArray, ...]  # per wheel: commanded rim speed
    sync_t: FloatArray  # (M,)
    counts: FloatArray  # (M, N) continuous encoder counts
    travel: FloatArray  # (M, N) counts / position_scale
    actual_speed: FloatArray  # (M, N) rim speed over the last SPEED_WINDOW_S (row 0: 0)
    poses: FloatArray  # (M, 3)
    stages: tuple[StageTrack, ...]
    emcy: tuple[EmcyEvent, ...]
    syncs: int  # every SYNC in the recording
    reboots: tuple[tuple[float, int], ...]  # (t, node id): boot-ups the host did not ask for
    node_frames: int  # frames from or to the configured nodes (0: wrong config?)
    #: the configured nodes the recording has frames from (a heartbeat, an EMCY, a TPDO)
    nodes_heard: frozenset[int] = frozenset()
    cut: str | None = None  # cut short or damaged: what was read and what not (cut_note)
    #: what the drives reported, each value of omnican.plan.health_fields but for a
    #: register, in its unit: quantity ("current" A, "torque" %, "voltage" V, "temperature"
    #: degC) -> per wheel (times, values); empty arrays where none came
    health: dict[str, tuple[tuple[FloatArray, FloatArray], ...]] = field(
        default_factory=dict)

    @property
    def complete_syncs(self) -> int:
        return int(self.sync_t.size)

    @property
    def num_wheels(self) -> int:
        return len(self.wheel_names)


@dataclass
class _Slot:
    field: int  # position among the PDO's fields (its codec's)
    role: str  # "target", "position", "statusword"
    index: int  # wheel index, or stage number


@dataclass
class _Stage:
    node_id: int
    wheels: list[int]
    changes: list[StateChange] = field(default_factory=list)


def _slots(layouts: Sequence[NodeLayout],
           first_stage: list[int]) -> dict[int, tuple[PdoCodec, list[_Slot]]]:
    """COB-ID -> the PDO's codec (the control loop's) and what of its fields replay reads,
    from the planned mapping."""
    out: dict[int, tuple[PdoCodec, list[_Slot]]] = {}
    for layout, base in zip(layouts, first_stage, strict=True):
        plan = layout.plan
        codecs = {tx: [PdoCodec(p) for p in (plan.tpdos if tx else plan.rpdos)]
                  for tx in (False, True)}
        wanted: list[tuple[Entry, bool, str, int]] = []
        for axis in layout.axes:
            wanted.append((axis.target, False, "target", axis.wheel_index))
            wanted.append((axis.position, True, "position", axis.wheel_index))
        for k, stage in enumerate(layout.stages):
            wanted.append((stage.statusword, True, "statusword", base + k))
        for entry, tx, role, index in wanted:
            for codec in codecs[tx]:
                i = codec.index_of(entry)
                if i is not None:
                    out.setdefault(codec.cob_id, (codec, []))[1].append(_Slot(i, role, index))
                    break
    return out


class _HealthSeries:
    """The health values in a recording, as the base reads them: its health TPDOs and
    the answers to its SDO reads (6075h's too, the rated current 6078h counts in)."""

    QUANTITIES = tuple(f.quantity for f in HEALTH_FIELDS if not f.register)

    def __init__(self, layouts: Sequence[NodeLayout], wheels: int) -> None:
        self.pdos: dict[int, tuple[PdoCodec, list[tuple[int, Any]]]] = {}
        self.sdo: dict[tuple[int, int, int], Any] = {}  # (node, index, sub) -> read
        self.rated: dict[tuple[int, int, int], list[Any]] = {}  # 6075h -> its current reads
        self.scales: dict[tuple[int, int, int], float] = {}
        self.series: dict[str, list[tuple[list[float], list[float]]]] = {
            q: [([], []) for _ in range(wheels)] for q in self.QUANTITIES}
        for layout in layouts:
            nid = layout.node_id
            reads = [r for r in layout.health.reads if r.quantity in self.QUANTITIES]
            for pdo in layout.health.pdos:
                codec = PdoCodec(pdo)
                fields = [(i, r) for r in reads if (i := codec.index_of(r.entry)) is not None]
                self.pdos[codec.cob_id] = (codec, [(i, (nid, r)) for i, r in fields])
            for r in reads:
                self.sdo[(nid, r.key[0], r.key[1])] = (nid, r)
                if r.quantity == "current" and r.scale is None:
                    axis = next(a for a in layout.axes if a.wheel_index == r.wheels[0])
                    rated = axis.objs.get(Obj.RATED_CURRENT)
                    if rated is not None:
                        self.rated.setdefault((nid, rated.index, rated.subindex), []).append(r)

    def take(self, cob: int, data: bytes | bytearray, t: float) -> bool:
        """True when the frame was one of the health reads (then recorded)."""
        pdo = self.pdos.get(cob)
        if pdo is not None:
            codec, fields = pdo
            values = codec.unpack(data)
            if values is not None:
                for i, (nid, read) in fields:
                    self._add(nid, read, values[i], t)
            return True
        if not SDO_ANSWER_BASE < cob <= SDO_ANSWER_BASE + 0x7F:
            return False
        answer = parse_answer(data)
        if answer is None or answer.kind is not AnswerKind.UPLOADED:
            return False
        nid = cob - SDO_ANSWER_BASE
        key = (nid, answer.index, answer.subindex)
        for read in self.rated.get(key, ()):
            raw = int.from_bytes(answer.data[:4], "little")
            self.scales[(nid, read.key[0], read.key[1])] = raw / 1_000_000.0
        found = self.sdo.get(key)
        if found is None:
            return False
        entry = found[1].entry
        self._add(nid, found[1], entry.decode(answer.data.ljust(entry.bits // 8, b"\x00")), t)
        return True

    def _add(self, nid: int, read: Any, raw: int, t: float) -> None:
        scale = (read.scale if read.scale is not None else
                 self.scales.get((nid, read.key[0], read.key[1])))
        if scale is None:
            return
        for wheel in read.wheels:
            times, values = self.series[read.quantity][wheel]
            times.append(t)
            values.append(raw * scale)

    def arrays(self) -> dict[str, tuple[tuple[FloatArray, FloatArray], ...]]:
        return {q: tuple((np.array(ts, dtype=np.float64), np.array(vs, dtype=np.float64))
                         for ts, vs in per_wheel) for q, per_wheel in self.series.items()}


def window_speeds(t: FloatArray, travel: FloatArray,
                  window_s: float = SPEED_WINDOW_S) -> FloatArray:
    """Speeds (M, N) at each row of ``travel`` (M, N) sampled at times ``t`` (M,): the
    travel since the latest sample at least ``window_s`` older (or the first sample),
    over the time between, as the chassis measures them (its WheelOdometry, which
    :func:`decode` runs); row 0 (and rows with no time between) are zero."""
    speed = np.zeros_like(travel)
    if len(t) < 2:
        return speed
    ref = np.searchsorted(t, t - window_s, side="right") - 1
    ref = np.clip(np.minimum(ref, np.arange(len(t)) - 1), 0, None)
    dt = t - t[ref]
    ok = dt > 0
    speed[ok] = (travel[ok] - travel[ref[ok]]) / dt[ok, None]
    return speed


def decode(frames: Iterable[Frame], cfg: ChassisConfig,
           layouts: Sequence[NodeLayout] | None = None) -> Replay:
    """Decode ``frames`` (any order; sorted by timestamp, stably) recorded on ``cfg``'s bus.

    ``layouts`` (``node_layouts(cfg)``) may be passed in to save parsing the EDS files."""
    if layouts is None:
        layouts = node_layouts(cfg)
    kin = cfg.kinematics()
    n = len(cfg.wheels)
    bits = [0] * n
    node_of = [0] * n
    for layout in layouts:
        for axis in layout.axes:
            bits[axis.wheel_index] = axis.position.bits
            node_of[axis.wheel_index] = layout.node_id
    stages: list[_Stage] = []
    first_stage: list[int] = []
    for layout in layouts:
        first_stage.append(len(stages))
        for k in range(len(layout.stages)):
            stages.append(_Stage(layout.node_id,
                                 [a.wheel_index for a in layout.axes if a.stage == k]))
    slots = _slots(layouts, first_stage)
    health = _HealthSeries(layouts, n)
    node_ids = {layout.node_id for layout in layouts}
    vscale = [w.velocity_scale for w in cfg.wheels]
    pscale = [w.position_scale for w in cfg.wheels]

    ordered = sorted(frames, key=lambda f: f.timestamp)
    t0 = ordered[0].timestamp if ordered else 0.0
    target_t: list[list[float]] = [[] for _ in range(n)]
    target_v: list[list[float]] = [[] for _ in range(n)]
    sync_t: list[float] = []
    counts_rows: list[list[float]] = []
    emcy: list[EmcyEvent] = []
    reboots: list[tuple[float, int]] = []
    booted: set[int] = set()
    reset: set[int] = set()  # nodes the host reset (NMT): their next boot-up is no reboot
    # Each wheel's newest position sample, tagged with its SYNC (syncs), as the loop's.
    samples = [CounterSampleSlot() for _ in range(n)]
    odo = WheelOdometry(Odometry(kin), EncoderCounters(samples, bits, pscale))
    poses_rows: list[tuple[float, float, float]] = []
    speed_rows: list[list[float]] = []
    current_sync: float | None = None
    reseed: set[int] = set()  # wheels whose drive rebooted since the SYNC
    syncs = 0
    node_frames = 0
    heard: set[int] = set()  # configured nodes that sent anything

    def close_sync() -> None:
        """The chassis' rule: integrate the SYNC's samples only if every wheel answered.
        A drive that rebooted meanwhile restarts its fold after that (its samples of the
        SYNC were taken before the reboot)."""
        if current_sync is not None and odo.integrate(syncs, current_sync):
            sync_t.append(current_sync)
            counts_rows.append(odo.counters.counts())
            poses_rows.append(odo.odometry.xyt)
            speed_rows.append(odo.speeds())
        for w in reseed:
            samples[w].restarts += 1
        reseed.clear()

    for frame in ordered:
        if getattr(frame, "is_error_frame", False) or getattr(frame, "is_remote_frame", False) \
                or getattr(frame, "is_extended_id", False):
            continue
        cob, data, t = frame.arbitration_id, frame.data, frame.timestamp - t0
        if cob == SYNC_COB_ID:
            close_sync()
            current_sync = t
            syncs += 1
            continue
        if cob in slots:
            node_frames += 1
            if cob & 0x780 in _TPDO_BASES:
                heard.add(cob & 0x7F)
            codec, read = slots[cob]
            values = codec.unpack(data)
            if values is None:
                continue  # not the planned PDO (or a broken frame), as the chassis ignores it
            for slot in read:
                value = values[slot.field]
                if slot.role == "target":
                    target_t[slot.index].append(t)
                    target_v[slot.index].append(value / vscale[slot.index])
                elif slot.role == "position":
                    if current_sync is not None:
                        sample = samples[slot.index]
                        sample.raw, sample.epoch = value, syncs
                else:
                    sw = value & 0xFFFF
                    state = decode_state(sw)
                    changes = stages[slot.index].changes
                    if not changes or changes[-1].state is not state:
                        changes.append(StateChange(t, state, sw))
            continue
        if health.take(cob, data, t):
            node_frames += 1
            continue
        if cob == NMT_COB_ID and len(data) >= 2:
            if data[0] in NMT_RESETS:
                reset.update(node_ids if data[1] == 0 else {data[1]})
            continue
        node = cob - EMCY_BASE
        if node in node_ids and len(data) >= 3:
            node_frames += 1
            heard.add(node)
            emcy.append(EmcyEvent(t, node, int.from_bytes(bytes(data[:2]), "little"), data[2]))
            continue
        node = cob - HEARTBEAT_BASE
        if node in node_ids and data:
            node_frames += 1
            heard.add(node)
            # boot-up: the counter restarts, the travel continues
            if data[0] & NMT_STATE_MASK == NmtState.BOOT_UP:
                if node in booted and node not in reset:
                    reboots.append((t, node))
                booted.add(node)
                reset.discard(node)
                reseed.update(w for w in range(n) if node_of[w] == node)
    close_sync()

    sync_arr = np.array(sync_t, dtype=np.float64)
    counts_arr = np.array(counts_rows, dtype=np.float64).reshape(-1, n)
    travel = counts_arr / np.array(pscale, dtype=np.float64)
    speed = np.array(speed_rows, dtype=np.float64).reshape(-1, n)
    poses = np.array(poses_rows, dtype=np.float64).reshape(-1, 3)
    names = tuple(f"wheel {i} ({w.name})" for i, w in enumerate(cfg.wheels))
    tracks = []
    for s in stages:
        wheels = ", ".join(str(w) for w in s.wheels)
        label = f"node {s.node_id} (wheel{'s' if len(s.wheels) > 1 else ''} {wheels})"
        tracks.append(StageTrack(s.node_id, tuple(s.wheels), label, tuple(s.changes)))
    duration = ordered[-1].timestamp - t0 if ordered else 0.0
    return Replay(
        start_time=t0,
        duration=duration,
        frames=len(ordered),
        wheel_names=names,
        target_t=tuple(np.array(v, dtype=np.float64) for v in target_t),
        target_speed=tuple(np.array(v, dtype=np.float64) for v in target_v),
        sync_t=sync_arr,
        counts=counts_arr,
        travel=travel,
        actual_speed=speed,
        poses=poses,
        stages=tuple(tracks),
        emcy=tuple(emcy),
        syncs=syncs,
        reboots=tuple(reboots),
        health=health.arrays(),
        node_frames=node_frames,
        nodes_heard=frozenset(heard),
    )


def load(path: str | Path, cfg: ChassisConfig) -> Replay:
    """Read and decode a recording made on ``cfg``'s base (one cut short or damaged: what
    could be read, with one warning; :attr:`Replay.cut` says what was not)."""
    frames, note = read_recording(path)
    if note:
        logger.warning("%s: %s", path, note)
    return replace(decode(frames, cfg), cut=note)
