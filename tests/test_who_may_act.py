"""Who may do what, one table (:data:`omnican.chassis.actions.RULES`) for every front end.

Each front end is driven in this process through the path its transport takes (the
terminal's keys and the gamepad as teleop's loop calls them; the ROS 2 bridge over an
in-memory DDS; Foxglove's listener and services as the SDK calls them; Zenoh on a
loopback router), against a real base in lock-step. For each action it offers, as the
driver, while another source drives, and while no one drives: what it answers and what
the base did match the table. Then the ROS 2 recover that did not ask (issue 39), the
docs' table, and a stop from another process while the keys drive.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import re
import sys
import time
from collections.abc import Callable, Iterator
from types import SimpleNamespace
from typing import Any, Protocol

import pytest

from omnican import Chassis, Twist
from omnican.chassis.actions import RULES, Action, Rule
from omnican.sim import SimulatedBase
from tests.support.helpers import ROOT, lockstep_rig

WAIT_S = 60.0  # real seconds, for what other threads do (generous: nothing is timed)
DRIVER, OTHER, NOBODY = "as the driver", "while another drives", "while no one drives"
SITUATIONS = (DRIVER, OTHER, NOBODY)
ANOTHER = "another front end"  # the source that drives in the OTHER situation
MOVE = Twist(0.2, 0.0, 0.0)  # how each front end's client drives
ACT = Twist(0.1, 0.1, 0.0)  # the command asked as the DRIVE action (told apart from MOVE)


def expected(action: Action, situation: str) -> bool:
    """Whether ``action`` is done in ``situation``, by the table's words."""
    return RULES[action] is Rule.ANYONE or situation != OTHER


class FrontEnd(Protocol):
    """One front end's client, driven through the front end's own entry points."""

    def drive(self) -> None:
        """The client drives (:data:`MOVE`), through the front end."""

    def act(self, action: Action) -> tuple[bool, str]:
        """The client asks ``action``: whether the front end said it was done, and what
        it said (for a refusal: who drives; "" where it says nothing but a count)."""


# ---------------------------------------------------------------- the front ends


class Teleop:
    """Teleop's keys (or its gamepad): what its loop calls for a movement, the stop key
    and the recover key (``omnican.cli.teleop``)."""

    def __init__(self, base: Chassis, gamepad: bool) -> None:
        from omnican.cli import teleop

        self.teleop = teleop
        self.source = base.command_source(teleop.source_name(gamepad))

    def drive(self) -> None:
        assert self.teleop.share_command(self.source, MOVE) is None

    def act(self, action: Action) -> tuple[bool, str]:
        t = self.teleop
        if action is Action.DRIVE:
            refused = t.share_command(self.source, ACT)
            return refused is None, t.refusal_note(self.source, refused) if refused else ""
        if action is Action.STOP:
            return True, t.stop_key(self.source)
        assert action is Action.RECOVER
        note = t.recover_note(t.recover_key(self.source, lambda text: None))
        return note == "", note


class Ros2:
    """The ROS 2 bridge: cmd_vel and the recover topic from one ROS 2 process (writer 1
    of the in-memory transport), polled as its thread polls."""

    def __init__(self, base: Chassis, sim: SimulatedBase) -> None:
        pytest.importorskip("cyclonedds", reason="needs the ros2 extra")
        from omnican.ros2 import msgs
        from omnican.ros2.bridge import Bridge
        from omnican.ros2.settings import Ros2Settings
        from tests.ros2.test_bridge import MemoryTransport

        self.msgs = msgs
        self.t = MemoryTransport()
        self.bridge = Bridge(base, Ros2Settings(), self.t, sim=sim, poll_thread=False)

    def _twist(self, t: Twist) -> Any:
        m = self.msgs
        return m.Twist(m.Vector3(t.vx, t.vy, 0.0), m.Vector3(0.0, 0.0, t.wz))

    def drive(self) -> None:
        self.t.deliver("/cmd_vel", self._twist(MOVE), writer=1)
        self.bridge.poll()

    def act(self, action: Action) -> tuple[bool, str]:
        bridge = self.bridge
        if action is Action.DRIVE:
            before = bridge.cmd_vel_refused
            self.t.deliver("/cmd_vel", self._twist(ACT), writer=1)
            bridge.poll()
            return bridge.cmd_vel_refused == before, ""
        assert action is Action.RECOVER
        bridge.recover_note = None
        self.t.deliver("/omnican/recover", self.msgs.Empty(), writer=1)
        bridge.poll()  # the recover runs on a thread of the bridge's
        assert wait_real(lambda: bridge.recover_note is not None), "no recover note"
        note = bridge.recover_note or ""
        return note.startswith("ok"), note

    def close(self) -> None:
        self.bridge.close()


class Foxglove:
    """Foxglove client 1 (vouched for by the relay): its Twists, the services and the
    parameters, as the SDK calls the control's listener and handlers."""

    def __init__(self, base: Chassis, sim: SimulatedBase) -> None:
        pytest.importorskip("foxglove", reason="needs the foxglove extra")
        from omnican.live.control import Control
        from omnican.live.settings import FoxgloveSettings
        from tests.live.test_control import attached, channel, client, vouch

        self.client = client(1)
        self.c = Control(base, FoxgloveSettings(control=True), sim=sim)
        vouch(self.c, 1)
        self.c.on_client_advertise(self.client, channel(1))
        self.board = attached(self.c)  # the status messages it sends its clients

    @staticmethod
    def _json(t: Twist) -> bytes:
        return json.dumps({"linear": {"x": t.vx, "y": t.vy, "z": 0.0},
                           "angular": {"x": 0.0, "y": 0.0, "z": t.wz}}).encode()

    def drive(self) -> None:
        self.c.on_message_data(self.client, 1, self._json(MOVE))

    def act(self, action: Action) -> tuple[bool, str]:
        from tests.live.test_control import call

        c = self.c
        if action is Action.DRIVE:
            before = c.twists
            c.on_message_data(self.client, 1, self._json(ACT))
            return c.twists == before + 1, (self.board.sent or [""])[-1]
        if action is Action.SET_LIMITS:
            [p] = c.on_set_parameters(self.client, [SimpleNamespace(
                name="chassis.max_speed", get_value=lambda: 0.25)])
            return p.get_value() == 0.25, self.board.sent[-1]
        name, body = {Action.STOP: ("/omnican/stop", None),
                      Action.RECOVER: ("/omnican/recover", None),
                      Action.RESET_POSE: ("/omnican/reset_odometry", {"x": 1.0}),
                      Action.SIM_CONSOLE: ("/omnican/sim/console",
                                           {"command": "battery 23"})}[action]
        reply = call(c, name, 1, body)
        return reply["success"], reply["message"]


class Zenoh:
    """A Zenoh client of the base's node on a loopback router: its cmd_vel publisher and
    its service calls carry one GID (one client), as the bridge's poll takes them."""

    GID = bytes([0xC1]) * 16

    def __init__(self, base: Chassis, router: str) -> None:
        pytest.importorskip("zenoh", reason="needs the zenoh extra")
        from omnican.zenoh.bridge import ZenohBridge, open_session
        from omnican.zenoh.settings import ZenohSettings
        from tests.zenoh.conftest import client

        settings = ZenohSettings(mode="client", connect=(router,))
        self._stack = contextlib.ExitStack()
        ours = open_session(settings)
        self._stack.callback(ours.close)
        self.session = client(router)
        self._stack.callback(self.session.close)
        self.bridge = self._stack.enter_context(
            ZenohBridge(base, settings, ours, poll_thread=False))
        self.pub = self.session.declare_publisher(self.bridge.cmd_key)
        self._stack.callback(self.pub.undeclare)
        assert wait_real(lambda: self.pub.matching_status.matching), "cmd_vel unmatched"
        self._sequence = itertools.count(1)

    def _publish(self, t: Twist) -> None:
        from omnican.telemetry import cdr
        from omnican.zenoh import rmw

        data = cdr.encode("geometry_msgs/msg/Twist", {
            "linear": {"x": t.vx, "y": t.vy, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0,
                                                                    "z": t.wz}})
        before = self.bridge.cmd_vel_count
        self.pub.put(data, attachment=rmw.Attachment(next(self._sequence), 0,
                                                     self.GID).encode())
        assert self._polled(lambda: self.bridge.cmd_vel_count > before), "cmd_vel not heard"

    def _polled(self, done: Callable[[], bool]) -> bool:
        """Poll the bridge (the sim's clock stands: whoever drives keeps driving) until
        ``done()``."""
        def poll() -> bool:
            self.bridge.poll()
            return done()
        return wait_real(poll)

    def drive(self) -> None:
        self._publish(MOVE)

    def act(self, action: Action) -> tuple[bool, str]:
        if action is Action.DRIVE:
            before = self.bridge.cmd_vel_refused
            self._publish(ACT)
            return self.bridge.cmd_vel_refused == before, ""
        from omnican.zenoh import rmw
        from omnican.zenoh.services import read_trigger_response, service_key

        name = {Action.HALT: "stop", Action.RECOVER: "recover",
                Action.RESET_POSE: "reset_odometry"}[action]
        got: list[Any] = []
        handler = self.session.get(service_key(self.bridge.node, name),
                                   payload=b"\x00\x01\x00\x00\x00",
                                   attachment=rmw.Attachment(next(self._sequence), 0,
                                                             self.GID).encode(),
                                   timeout=WAIT_S)

        def answered() -> bool:
            reply = handler.try_recv()
            if reply is not None:
                got.append(reply)
            return bool(got)

        assert self._polled(answered), f"no answer to ~/{name}"
        assert got[0].ok is not None, got[0]
        return read_trigger_response(got[0].ok.payload.to_bytes())

    def close(self) -> None:
        self._stack.close()


#: What each front end offers, by the table's actions.
OFFERS: dict[str, tuple[Action, ...]] = {
    "teleop keys": (Action.DRIVE, Action.STOP, Action.RECOVER),
    "teleop gamepad": (Action.DRIVE, Action.STOP, Action.RECOVER),
    "ROS 2": (Action.DRIVE, Action.RECOVER),
    "Foxglove": (Action.DRIVE, Action.STOP, Action.RECOVER, Action.RESET_POSE,
                 Action.SET_LIMITS, Action.SIM_CONSOLE),
    "Zenoh": (Action.DRIVE, Action.HALT, Action.RECOVER, Action.RESET_POSE),
}


@contextlib.contextmanager
def front_end(name: str, base: Chassis, sim: SimulatedBase,
              request: pytest.FixtureRequest) -> Iterator[FrontEnd]:
    if name.startswith("teleop"):
        yield Teleop(base, gamepad=name.endswith("gamepad"))
    elif name == "Foxglove":
        yield Foxglove(base, sim)
    else:
        made = Ros2(base, sim) if name == "ROS 2" else Zenoh(base,
                                                             request.getfixturevalue("router"))
        try:
            yield made
        finally:
            made.close()


def wait_real(done: Callable[[], bool]) -> bool:
    deadline = time.monotonic() + WAIT_S
    while not done():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


@pytest.fixture
def router() -> Iterator[str]:
    from tests.zenoh.conftest import free_port

    zenoh = pytest.importorskip("zenoh", reason="needs the zenoh extra")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    try:
        yield endpoint
    finally:
        session.close()


#: What the base (or the simulator, for its console) is asked when an action is done.
EFFECTS = {Action.DRIVE: "set_twist", Action.STOP: "stop", Action.HALT: "halt",
           Action.RECOVER: "recover", Action.RESET_POSE: "reset_pose",
           Action.SET_LIMITS: "set_limits", Action.SIM_CONSOLE: "set_battery"}


def spy(base: Chassis, sim: SimulatedBase, monkeypatch: pytest.MonkeyPatch
        ) -> list[tuple[str, tuple[Any, ...]]]:
    """Every call of what the actions ask of the base and the simulator, in order."""
    calls: list[tuple[str, tuple[Any, ...]]] = []
    for owner, name in [*((base, n) for n in EFFECTS.values() if n != "set_battery"),
                        (sim, "set_battery")]:
        real = getattr(owner, name)

        def recorded(*args: Any, _real: Any = real, _name: str = name, **kw: Any) -> Any:
            calls.append((_name, args + tuple(kw.values())))
            return _real(*args, **kw)

        monkeypatch.setattr(owner, name, recorded)
    return calls


CASES = [pytest.param(fe, action, situation, id=f"{fe}-{action.value}-{situation}")
         for fe, actions in OFFERS.items() for action in actions for situation in SITUATIONS]


@pytest.mark.parametrize(("name", "action", "situation"), CASES)
def test_every_front_end_answers_by_the_one_table(
        name: str, action: Action, situation: str, channel: str,
        monkeypatch: pytest.MonkeyPatch, request: pytest.FixtureRequest) -> None:
    with lockstep_rig(channel) as (_, sim, base), front_end(name, base, sim, request) as fe:
        another = base.command_source(ANOTHER)
        if situation == DRIVER:
            fe.drive()
        elif situation == OTHER:
            assert another.drive(Twist(0.05, 0.0, 0.0)).ok
        calls = spy(base, sim, monkeypatch)
        done, said = fe.act(action)
        effect = EFFECTS[action]
        did = any(n == effect and (action is not Action.DRIVE or args == (ACT,))
                  for n, args in calls)
        want = expected(action, situation)
        assert (done, did) == (want, want), (said, calls)
        if not want and said:
            assert ANOTHER in said, said  # a refusal names who drives
        if want and action.stops and situation == OTHER:  # it took control from the driver
            assert not another.drive(Twist(0.05, 0.0, 0.0)).ok
            assert another.stopped_by() is not None


def test_every_action_of_the_table_is_offered_by_a_front_end() -> None:
    assert set(itertools.chain(*OFFERS.values())) == set(RULES) == set(Action)


# ---------------------------------------------------------------- the bug that drifted


def test_a_ros2_recover_while_a_foxglove_client_drives_keeps_its_command(
        channel: str) -> None:
    """Issue 39: the ROS 2 bridge's recover called ``base.recover()`` without asking
    the arbiter, so a ``~/recover`` while a Foxglove client drove zeroed that client's
    command (the base stopped under it). It is refused now, naming the client, and the
    client's command stands."""
    pytest.importorskip("foxglove", reason="needs the foxglove extra")
    pytest.importorskip("cyclonedds", reason="needs the ros2 extra")
    from omnican.ros2 import msgs
    from tests.live.test_control import client

    with lockstep_rig(channel) as (clock, sim, base):
        fox = Foxglove(base, sim)
        ros2 = Ros2(base, sim)
        try:
            def driving() -> bool:
                fox.drive()  # the client's Teleop panel streams its Twist
                return sim.true_twist.vx == pytest.approx(MOVE.vx, abs=0.01)

            assert clock.run_until(driving, 3.0, 0.02)
            ros2.t.deliver("/omnican/recover", msgs.Empty(), writer=9)  # another process
            ros2.bridge.poll()
            assert wait_real(lambda: ros2.bridge.recover_note is not None)
            assert (ros2.bridge.recover_note or "").startswith(
                "refused: Foxglove client 1 is driving the base"), ros2.bridge.recover_note
            clock.sleep(0.3)  # within the client's command timeout: it still drives
            assert base.command == MOVE
            assert sim.true_twist.vx == pytest.approx(MOVE.vx, abs=0.01)
            assert base.command_source("a test").holder() == fox.c.source(client(1).id)
        finally:
            ros2.close()


# ---------------------------------------------------------------- the docs' table


def test_the_docs_table_is_the_codes() -> None:
    """docs/safety.md's "Who may act" table says what :data:`RULES` says, row by row."""
    page = (ROOT / "docs" / "safety.md").read_text()
    section = page[page.index("## Who may act"):]
    section = section[:section.index("\n## ", 1)]
    rows = re.findall(r"^\| ([^|]+?) \| ([^|]+?) \| [^|]+ \|$", section, re.M)
    table = {action: who for action, who in rows if action != "action"}
    assert table == {a.value: rule.value for a, rule in RULES.items()}


# ---------------------------------------------------------------- across processes


def test_a_stop_from_another_process_stops_whoever_drives_and_the_console_asks_too(
        router: str) -> None:
    """``omnican zenoh --sim`` in a process of its own, a cmd_vel publisher in another
    driving it, and this process a Zenoh service client. While the publisher drives, the
    base's own console's ``recover`` and this client's ``~/reset_odometry`` are refused
    and name it (the console recovered at once before, zeroing the publisher's command);
    this client's ``~/stop`` stops the base and holds it, the publisher still sending;
    with no one driving then, the console's ``recover`` is done and the base stays still
    (the publisher, still sending, is out until it lets go)."""
    from omnican.telemetry import cdr
    from omnican.zenoh import rmw
    from omnican.zenoh.services import read_trigger_response, service_key
    from tests.interop.ros2_interop.harness import Proc
    from tests.zenoh.conftest import client
    from tests.zenoh.test_fleet_cli import cmd_vel

    odom_type = "nav_msgs/msg/Odometry"
    session = client(router)
    speeds: list[float] = []

    def heard(sample: Any) -> None:
        speeds.append(cdr.decode(odom_type, sample.payload.to_bytes())["twist"]["twist"]
                      ["linear"]["x"])

    odom = session.declare_subscriber(rmw.data_key(0, "/odom", odom_type,
                                                   rmw.type_hash(odom_type)), heard)
    node = rmw.RosNode(0, "0", 0, "omnican", namespace="/")
    calls = itertools.count(1)

    def call(name: str) -> tuple[bool, str]:
        replies = session.get(service_key(node, name), payload=b"\x00\x01\x00\x00\x00",
                              attachment=rmw.Attachment(next(calls), 0, bytes(16)).encode(),
                              timeout=WAIT_S)
        [reply] = [r for r in replies if r.ok is not None]
        return read_trigger_response(reply.ok.payload.to_bytes())

    def speed_is(vx: float) -> bool:
        return wait_real(lambda: bool(speeds) and abs(speeds[-1] - vx) < 0.01)

    base = Proc([sys.executable, "-m", "omnican", "zenoh", "--sim", "--zenoh-mode",
                 "client", "--zenoh-connect", router], env=dict(os.environ))
    try:
        assert base.read_until(lambda line: "Ctrl-C to stop" in line, WAIT_S), base.lines
        publisher = f"Zenoh cmd_vel publisher {bytes(range(16)).hex()}"
        with cmd_vel(router, "/cmd_vel", 0.2):  # from a third process, at 20 Hz
            assert speed_is(0.2), speeds[-5:]
            base.send("recover")
            said = base.read_until(lambda line: line.startswith("recover"), WAIT_S)
            assert said == f"recover refused: {publisher} is driving the base", base.lines
            assert call("reset_odometry") == (False, f"{publisher} is driving the base")
            assert call("stop") == (True, "stopped: held until recover")
            assert speed_is(0.0), speeds[-5:]  # stopped under a publisher still sending
            base.send("recover")  # no one drives: anyone may
            assert base.read_until(lambda line: line.startswith("recover"), WAIT_S) == \
                "recovered", base.lines
            heard_then = len(speeds)
            assert wait_real(lambda: len(speeds) > heard_then + 20)  # a second of odometry
            assert all(abs(vx) < 0.01 for vx in speeds[heard_then:]), speeds[heard_then:]
    finally:
        base.kill()
        odom.undeclare()
        session.close()
