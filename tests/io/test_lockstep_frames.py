"""The lock-step bus's frame path: a standard data frame handed to a peer as values
(COB-ID, data, timestamp), no message made, where nothing but canopen's subscribers and
the traffic count hears it. What the subscribers get, the traffic counted and the frames
the simulated drives send must be those of the message path (the bus's own
:meth:`~omnican.io.bus.CanBus._dispatch`, the network's lock-step receiver)."""

from __future__ import annotations

import contextlib
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from omnican.clock import SimClock
from omnican.errors import OmnicanError
from omnican.io.bus import CanBus
from omnican.io.lockstep import LockstepBus
from omnican.io.network import Network
from tests.support.helpers import lockstep_rig
from tests.support.sim_steps import act, record_drive_frames

Call = tuple[int, bytes, str, float]

_FRAMES = st.lists(st.tuples(
    st.integers(0, 0x7FF) | st.sampled_from([0x080, 0x181, 0x182, 0x281, 0x581, 0x701, 0x703]),
    st.binary(max_size=8),
    st.sampled_from(["plain", "plain", "plain", "extended", "remote", "error", "fd",
                     "short dlc"]),
    st.floats(0, 1e4, allow_nan=False)), max_size=20)


def _message(can_id: int, data: bytes, kind: str, stamp: float) -> can.Message:
    """A received frame as the lock-step bus makes it for the message path."""
    return can.Message(timestamp=stamp, arbitration_id=can_id, data=bytearray(data),
                       is_extended_id=kind == "extended", is_remote_frame=kind == "remote",
                       is_error_frame=kind == "error", is_fd=kind == "fd",
                       dlc=(len(data) - 1 if data else 1) if kind == "short dlc" else len(data),
                       channel="ch", is_rx=True)


def _recorder(calls: list[Call], name: str, fail_on: int | None = None
              ) -> Callable[[int, bytearray, float], None]:
    def callback(can_id: int, data: bytearray, stamp: float) -> None:
        calls.append((can_id, bytes(data), type(data).__name__, stamp))
        calls.append((-1, name.encode(), "", 0.0))
        if can_id == fail_on:
            raise ValueError("a broken subscriber")
    return callback


def _subscribe(network: Any, calls: list[Call]) -> None:
    """Subscribers on a few COB-IDs, two on one, one that raises (after the others)."""
    network.subscribe(0x181, _recorder(calls, "a"))
    network.subscribe(0x181, _recorder(calls, "b"))
    network.subscribe(0x281, _recorder(calls, "c", fail_on=0x281))
    network.subscribe(0x701, _recorder(calls, "d"))


@given(frames=_FRAMES)
def test_a_peer_gets_a_plain_frame_as_values_and_any_other_as_the_message(
        frames: list[tuple[int, bytes, str, float]]) -> None:
    """A standard data frame whose dlc is its length reaches a frame receiver as values
    (the data a bytearray of its own); an extended, remote, error or FD frame, one whose
    dlc differs, or one the frame receiver declines reaches the message receiver as the
    message a peer without a frame receiver gets."""
    clock = SimClock()
    buses = [LockstepBus("ch", clock) for _ in range(3)]
    sender, plain_peer, framed_peer = buses
    try:
        as_messages: list[can.Message] = []
        plain_peer.set_receiver(as_messages.append)
        got_frames: list[tuple[int, bytearray, float]] = []
        got_messages: list[can.Message] = []
        declined: list[int] = []

        def frames_in(can_id: int, data: bytearray, stamp: float) -> bool:
            if can_id % 5 == 0:  # declined: it wants this one as a message
                declined.append(can_id)
                return False
            got_frames.append((can_id, data, stamp))
            return True

        framed_peer.set_receiver(got_messages.append, frames_in)
        for can_id, data, kind, dt in frames:
            clock.sleep(dt)
            msg = _message(can_id, data, kind, 0.0)
            msg.data = bytes(data)  # type: ignore[assignment]  # as omnican sends them
            sender.send(msg)
        assert len(as_messages) == len(frames)
        frame_iter, message_iter = iter(got_frames), iter(got_messages)
        for sent, want in zip(frames, as_messages, strict=True):
            can_id, data, kind, _ = sent
            if kind == "plain" and can_id % 5 != 0:
                got_id, got_data, stamp = next(frame_iter)
                assert (got_id, bytes(got_data), stamp) == (can_id, data, want.timestamp)
                assert isinstance(got_data, bytearray)
            else:
                got = next(message_iter)
                assert got.equals(want, timestamp_delta=0.0)
                assert (got.is_rx, got.channel) == (want.is_rx, want.channel)
        assert next(frame_iter, None) is None and next(message_iter, None) is None
        assert declined == [i for i, _, kind, _ in frames if kind == "plain" and i % 5 == 0]
        # A message receiver set alone drops the frame receiver (a wrapper sees them all).
        framed_peer.set_receiver(got_messages.append)
        before = len(got_frames)
        sender.send(_message(0x181, b"\x01", "plain", 0.0))
        assert len(got_frames) == before and got_messages[-1].arbitration_id == 0x181
    finally:
        for bus in buses:
            bus.shutdown()


@given(st.integers(0, 0x7FF), st.binary(max_size=8), st.booleans())
def test_send_frame_is_send_of_a_standard_data_frame(can_id: int, data: bytes,
                                                     queued: bool) -> None:
    """A frame sent as values (what a simulated drive sends) reaches a peer without a
    frame receiver, or one reading through recv(), as the message send() makes of it."""
    clock = SimClock()
    sender, peer = LockstepBus("ch", clock), LockstepBus("ch", clock)
    try:
        got: list[can.Message] = []
        if not queued:
            peer.set_receiver(got.append)
        sender.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
        sender.send_frame(can_id, data)
        if queued:
            got = [m for m in (peer.recv(0), peer.recv(0)) if m is not None]
        assert len(got) == 2 and got[0].equals(got[1], timestamp_delta=0.0)
        fields = [f for f in can.Message.__slots__ if f != "__weakref__"]
        assert [(getattr(got[0], f), type(getattr(got[0], f))) for f in fields] == \
            [(getattr(got[1], f), type(getattr(got[1], f))) for f in fields]
    finally:
        sender.shutdown()
        peer.shutdown()


def test_who_hears_a_frame_follows_peers_joining_leaving_and_changing_receivers() -> None:
    """The peers a bus sends to are listed again after any change: a bus that joins the
    channel hears what is sent next, one shut down hears nothing more, a new frame
    receiver (or none) applies from the next frame."""
    clock = SimClock()
    sender, first = LockstepBus("ch-join", clock), LockstepBus("ch-join", clock)
    heard: list[tuple[str, int]] = []

    def frames_of(name: str) -> Callable[[int, bytearray, float], bool]:
        def take(can_id: int, data: bytearray, stamp: float) -> bool:
            heard.append((name, can_id))
            return True
        return take

    first.set_receiver(lambda m: heard.append(("first message", m.arbitration_id)),
                       frames_of("first"))
    sender.send_frame(0x101, b"")
    second = LockstepBus("ch-join", clock)
    try:
        second.set_receiver(lambda m: heard.append(("second message", m.arbitration_id)))
        sender.send_frame(0x102, b"")
        first.set_receiver(lambda m: heard.append(("first message", m.arbitration_id)))
        second.set_receiver(lambda m: None, frames_of("second"))
        sender.send_frame(0x103, b"")
        first.shutdown()
        sender.send_frame(0x104, b"")
        assert heard == [("first", 0x101), ("first", 0x102), ("second message", 0x102),
                         ("first message", 0x103), ("second", 0x103), ("second", 0x104)]
    finally:
        for bus in (sender, first, second):
            bus.shutdown()


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=_FRAMES)
def test_the_hosts_frame_dispatch_is_its_message_dispatch(
        channel: str, frames: list[tuple[int, bytes, str, float]]) -> None:
    """CanBus._dispatch_frame calls the subscribers as _dispatch does (the same calls in
    the same order, a failing subscriber logged, not raised) and counts the same traffic."""
    clock = SimClock()
    runs: list[tuple[list[Call], int, int]] = []
    for path in ("message", "frame"):
        calls: list[Call] = []
        with CanBus({"interface": "virtual",
                     "channel": f"{channel}-{path}-{uuid.uuid4().hex[:8]}"},
                    clock=clock) as bus:
            _subscribe(bus.network, calls)
            for can_id, data, kind, stamp in frames:
                if kind != "plain":
                    continue
                if path == "message":
                    bus._dispatch(_message(can_id, data, kind, stamp))
                else:
                    assert bus._dispatch_frame(can_id, bytearray(data), stamp) is True
            runs.append((calls, bus.traffic.loop_frames, bus.traffic.loop_bits))
    assert runs[0] == runs[1]


def test_the_host_wants_messages_while_a_recorder_or_a_tap_listens(channel: str) -> None:
    """A recorder or a tap hears every frame as a message: _dispatch_frame declines
    (False) and counts nothing; the frame then goes the message way, to them too."""
    clock = SimClock()
    heard: list[can.Message] = []

    class Tap(can.Listener):
        def on_message_received(self, msg: can.Message) -> None:
            heard.append(msg)

    with CanBus({"interface": "virtual", "channel": channel}, clock=clock) as bus, \
            LockstepBus(channel, clock) as other:
        calls: list[Call] = []
        _subscribe(bus.network, calls)
        tap = Tap()
        bus.add_listener(tap)
        assert bus._dispatch_frame(0x181, bytearray(b"\x01"), 1.0) is False
        assert calls == [] and bus.traffic.loop_frames == 0
        other.send(can.Message(arbitration_id=0x181, data=b"\x02", is_extended_id=False))
        assert [m.arbitration_id for m in heard] == [0x181]
        assert [c[1] for c in calls if c[0] == 0x181] == [b"\x02", b"\x02"]
        bus.remove_listener(tap)
        assert bus._dispatch_frame(0x181, bytearray(b"\x03"), 1.0) is True
        assert len(heard) == 1 and bus.traffic.loop_frames == 2


@given(frames=_FRAMES)
def test_the_networks_frame_receiver_is_its_lockstep_receiver(
        frames: list[tuple[int, bytes, str, float]]) -> None:
    """The simulator's network: its frame receiver calls canopen's subscribers and its
    node scanner as its lock-step receiver does; with another listener on the network it
    declines (that listener hears the message)."""
    runs: list[tuple[list[Call], list[int]]] = []
    for path in ("message", "frame"):
        network = Network()
        calls: list[Call] = []
        _subscribe(network, calls)
        receive, receive_frame = network.lockstep_receiver(), network.lockstep_frame_receiver()
        for can_id, data, kind, stamp in frames:
            if kind != "plain":
                continue
            if path == "message":
                receive(_message(can_id, data, kind, stamp))
            else:
                assert receive_frame(can_id, bytearray(data), stamp) is True
        runs.append((calls, list(network.scanner.nodes)))
    assert runs[0] == runs[1]
    network = Network()
    calls = []
    _subscribe(network, calls)
    network.listeners.append(can.BufferedReader())  # type: ignore[arg-type]
    assert network.lockstep_frame_receiver()(0x181, bytearray(b"\x01"), 0.0) is False
    assert calls == [] and network.scanner.nodes == []


# ------------------------------------------------------ the demo base, both ways

_ACTIONS = st.one_of(
    st.tuples(st.just("drive"), st.sampled_from([(0.3, 0.0, 0.0), (0.0, 0.2, 0.5),
                                                 (-0.2, 0.1, -0.4), (0.0, 0.0, 0.0)])),
    st.tuples(st.just("fault"), st.integers(0, 2)),
    st.tuples(st.just("estop"), st.booleans()),
    st.tuples(st.just("stop_heartbeat"), st.integers(0, 2)),
    st.tuples(st.just("recover"),),
    st.tuples(st.just("halt"),),
    st.tuples(st.just("sdo"), st.integers(0, 2)),
)
_STEPS = st.lists(st.tuples(_ACTIONS, st.sampled_from([0.0, 0.01, 0.03, 0.2, 0.6])),
                  min_size=1, max_size=6)


@contextlib.contextmanager
def _messages_only() -> Iterator[None]:
    """The lock-step bus as it was: every frame to every peer as a message."""
    real = LockstepBus.set_receiver

    def receiver_only(self: LockstepBus, receiver: Any, frames: Any = None) -> None:
        real(self, receiver)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(LockstepBus, "set_receiver", receiver_only)
        yield


def _run(channel: str, steps: list[tuple[tuple[Any, ...], float]]) -> list[Any]:
    """What the drives send (time, COB-ID, data) and what the host makes of what it
    receives (its wheels, pose, status, traffic), after each step."""
    seen: list[Any] = []
    with lockstep_rig(channel) as (clock, sim, base):
        record_drive_frames(sim, clock, seen)
        clock.sleep(0.1)
        for action, dt in steps:
            with contextlib.suppress(OmnicanError):
                act(action, sim, base)
            clock.sleep(dt)
            seen.append((base.wheels, base.pose, base.twist, base.status.stopped_reason,
                         base.bus.traffic.frames, base.bus.traffic.bits,
                         sorted(sim.network.scanner.nodes)))
    return seen


@settings(max_examples=15, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(steps=_STEPS)
def test_the_demo_base_runs_the_same_with_frames_as_with_messages(
        channel: str, steps: list[tuple[tuple[Any, ...], float]]) -> None:
    """Driving, faults, an e-stop, a lost heartbeat, recovering, halting, SDO requests:
    the drives send the same frames at the same instants, and the host sees the same,
    whether the lock-step bus hands frames over as values or as messages."""
    framed = _run(f"{channel}-frames", steps)
    with _messages_only():
        messages = _run(f"{channel}-messages", steps)
    assert framed == messages
