"""Random steps against a simulated base in lock-step, for the property tests that hold a
fast path to the slow one (tests/sim/test_event_tpdos.py, tests/io/test_lockstep_frames.py):
what a step does to the drives or the base, and every frame the drives send."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

#: (simulated time, COB-ID, data) of a frame a simulated drive sent
Frame = tuple[float, int, bytes]


def act(action: tuple[Any, ...], sim: Any, base: Any) -> None:
    """Do ``action`` (its kind, then its arguments) to the simulated drives or the base."""
    kind, *args = action
    if kind == "drive":
        base.set_velocity(*args[0])
    elif kind == "fault":
        sim.drives[args[0]].inject_fault()
    elif kind == "estop":
        for drive in sim.drives:
            drive.estop(args[0])
    elif kind == "following":
        drive = sim.drives[args[0]]
        drive.inject_following_error() if args[1] else drive.clear_following_error()
    elif kind == "jam":
        drive = sim.drives[args[0]]
        drive.jam() if args[1] else drive.free()
    elif kind == "push":
        sim.drives[args[0]].push(args[1])
    elif kind == "window":  # 606Dh, as an SDO download writes it
        sim.drives[args[0]].node.sdo[0x606D].raw = args[1]
    elif kind == "mode":  # 6060h, written behind the host's back
        sim.drives[args[0]].node.sdo[0x6060].raw = args[1]
    elif kind == "stop_heartbeat":
        sim.drives[args[0]].stop_heartbeat()
    elif kind == "recover":
        base.recover(timeout_s=0.5)
    elif kind == "halt":
        base.halt("test")
    elif kind == "sdo":  # an SDO upload from the host's side, answered inside its request
        base.nodes[args[0]].remote.sdo.upload(0x6041, 0)
    else:
        raise ValueError(f"no such step: {kind!r}")


def record_drive_frames(sim: Any, clock: Any, frames: list[Any]) -> None:
    """Append every frame ``sim``'s drives send from now on to ``frames``, as a
    :data:`Frame` at ``clock``'s time."""
    def recorded(send: Callable[[int, bytes], None]) -> Callable[[int, bytes], None]:
        def send_recorded(cob_id: int, data: bytes) -> None:
            frames.append((clock.now(), cob_id, bytes(data)))
            send(cob_id, data)
        return send_recorded

    for drive in sim.drives:
        drive.comm._tx.send = recorded(drive.comm._tx.send)
