"""Driving from Foxglove, tested with Foxglove's own client library: ``@foxglove/ws-protocol``
(npm, on Node.js; tests/interop/foxglove_node/) against ``omnican drive --sim`` and ``omnican
ros2 --sim`` as separate processes. It advertises /cmd_vel, publishes Twists (JSON, and
CDR written by Foxglove's ROS 2 serializer, as the app's Teleop panel does), calls the
services and sets parameters; the motion is checked against the simulator's truth
(``--json`` prints ``true_pose``; the live view's ``/twist`` and ``/sim/pose2d``).

Installed once into ~/.cache/omnican/foxglove-node (about 2 s from npm); skipped, with
the reason, where Node.js or npm is missing or the packages cannot be installed. Every
server binds to 127.0.0.1.
"""

from __future__ import annotations

import base64
import json
import re
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.interop.foxglove_node.harness import (
    NodeClient,
    Omnican,
    json_line,
    listening_ports,
    node_modules,
)
from tests.support import terminal

LEGACY, SDK = "foxglove.websocket.v1", "foxglove.sdk.v1"

pytestmark = pytest.mark.timeout(300)  # the first run installs the npm packages

DEMO_BASE = """\
[chassis]
layout = "b21"
base_radius = 0.19
cmd_timeout_s = {timeout}
{wheels}
{extra}
"""
WHEEL = "[[wheel]]\nnode_id = {n}\ngear_ratio = 16\nencoder_cpr = 4096\nwheel_radius = 0.05\n"


@pytest.fixture(scope="module")
def modules() -> Path:
    path, note = node_modules()
    if path is None:
        pytest.skip(note)
    print(f"Foxglove Node client: {note}")
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def top_speed(path: str) -> float:
    """The top linear speed the config's base can reach (what an unlimited
    ``chassis.max_speed`` reads as, a number)."""
    from omnican import load_config
    from omnican.core.limits import top_speeds

    cfg = load_config(path)
    return top_speeds(cfg.limits(), cfg.kinematics())[0]


def config(tmp_path: Path, timeout_s: float = 0.5, extra: str = "") -> str:
    path = tmp_path / "robot.toml"
    path.write_text(DEMO_BASE.format(timeout=timeout_s, extra=extra,
                                     wheels="\n".join(WHEEL.format(n=n) for n in (1, 2, 3))))
    return str(path)


class Session:
    """An omnican process and the Node clients connected to it, all ended at the end."""

    def __init__(self, modules: Path, *args: str) -> None:
        self.modules = modules
        self.omnican = Omnican(*args)
        self.clients: list[NodeClient] = []
        self.url = self.omnican.url()

    def client(self, protocols: str = SDK, query: str = "", origin: str | None = None,
               url: str | None = None, connect: bool = True) -> NodeClient:
        """A Node client on ``url`` (default omnican's) + ``query`` (``/?token=...``), as
        opened by a web page at ``origin``; with ``connect``, waits until it is."""
        c = NodeClient(self.modules, (url or self.url) + query, protocols, origin)
        self.clients.append(c)
        if connect:
            c.connected()
        return c

    def close(self) -> None:
        for c in self.clients:
            c.close()
        self.omnican.kill()
        print("omnican said:\n" + self.omnican.finish()[1])


@pytest.fixture
def sessions(modules: Path) -> Iterator[list[Session]]:
    made: list[Session] = []
    yield made
    for s in made:
        s.close()


def start(sessions: list[Session], modules: Path, *args: str) -> Session:
    s = Session(modules, *args)
    sessions.append(s)
    return s


def twist_of(event: dict[str, Any], kind: str) -> tuple[float, float, float]:
    t = event["json"][kind]
    return t["vx"], t["vy"], t["wz"]


def test_teleop_twists_services_and_parameters_drive_the_simulated_base(
        modules: Path, sessions: list[Session], tmp_path: Path) -> None:
    """One client on the protocol's old name (foxglove.websocket.v1, as Foxglove Studio
    and Lichtblick offer it) drives with JSON Twists after lowering chassis.max_speed,
    leaves control; a second on foxglove.sdk.v1 turns with CDR Twists, then uses the
    services. Where the simulator says the base went is what they commanded."""
    toml = config(tmp_path, extra="[foxglove]\ncontrol = true\n")
    top = top_speed(toml)
    s = start(sessions, modules, "drive", "--sim", "--config", toml, "--foxglove",
              f"127.0.0.1:{free_port()}", "--duration", "14", "--json")
    a = s.client(LEGACY)
    opened = next(e for e in a.events if e["event"] == "open")
    assert opened["protocol"] == LEGACY
    assert {"clientPublish", "services", "parameters"} <= set(a.server_info["capabilities"])
    services = a.wait("advertiseServices")["services"]
    assert set(services) == {"/omnican/stop", "/omnican/recover", "/omnican/reset_odometry",
                             "/omnican/sim/console"}
    # Parameters: named as the config keys; a value out of range is refused with the reason.
    a.send("getParameters", names=[], id="all")
    values = {p["name"]: p["value"] for p in a.wait("parameterValues")["parameters"]}
    # unlimited: the top speed the base can reach, a number (Foxglove shows it as one)
    assert values["chassis.max_speed"] == pytest.approx(top)
    assert values["chassis.max_accel"] == 1
    assert values["chassis.max_wheel_speed"] == 1
    a.send("setParameters", parameters=[{"name": "chassis.max_speed", "value": -1}], id="bad")
    reply = a.wait("parameterValues", lambda e: e["id"] == "bad")
    [unchanged] = reply["parameters"]
    assert unchanged["name"] == "chassis.max_speed"
    assert unchanged["value"] == pytest.approx(top)
    refusal = a.wait("status", lambda e: "refused" in e["message"])["message"]
    assert "chassis.max_speed: must be a positive number, got -1" in refusal
    a.send("setParameters", parameters=[{"name": "chassis.max_speed", "value": 0.1}], id="ok")
    reply = a.wait("parameterValues", lambda e: e["id"] == "ok")
    assert reply["parameters"][0]["value"] == pytest.approx(0.1)
    # Drive: 0.3 m/s asked for 2 s, 0.1 m/s allowed (from the next cycle on).
    a.send("advertise", topic="/cmd_vel", encoding="json", schemaName="geometry_msgs/Twist")
    channel = a.wait("advertised")["channel"]
    a.send("publish", channel=channel, twist=[0.3, 0.0, 0.0], rate_hz=10, seconds=2)
    a.wait("published", timeout=10)
    a.send("unadvertise", channel=channel)  # the panel goes: the base stops, control is free
    a.wait("unadvertised")
    # The second client turns: CDR, as Foxglove's serializer writes it.
    b = s.client(SDK)
    b.send("advertise", topic="/cmd_vel", encoding="cdr", schemaName="geometry_msgs/Twist")
    channel = b.wait("advertised")["channel"]
    b.send("publish", channel=channel, twist=[0.0, 0.0, 0.5], rate_hz=10, seconds=2)
    b.wait("published", timeout=10)
    assert not any("is driving the base" in m for m in b.statuses())
    # Services: a fault from the console latches a stop, recover clears it, odometry resets.
    b.send("call", service="/omnican/sim/console", request={"command": "fault 2"})
    assert b.wait("response")["data"] == {"success": True, "message": "node 2: fault 0x2310"}
    b.send("call", service="/omnican/recover")
    assert b.wait("response", timeout=30)["data"] == {
        "success": True, "message": "recovered: every drive enabled"}
    b.send("call", service="/omnican/reset_odometry", request={"x": 1.0, "theta": "half"})
    assert b.wait("response")["data"] == {"success": False,
                                          "message": "theta must be a number, got 'half'"}
    b.send("call", service="/omnican/reset_odometry", request={"x": 1.0, "y": -0.5})
    assert b.wait("response")["data"]["success"] is True
    b.send("call", service="/omnican/sim/console", request={"command": "quit"})
    assert b.wait("response")["data"]["success"] is False
    code, out = s.omnican.finish(timeout=40)
    assert code == 0, out
    result = json_line(out)
    truth = result["true_pose"]
    # 0.1 m/s for about 2 s (the limiter's ramps take a little), then a turn of 0.5 rad/s
    # for about 2 s in place.
    assert truth["x"] == pytest.approx(0.2, abs=0.04)
    assert truth["y"] == pytest.approx(0.0, abs=0.02)
    assert truth["theta"] == pytest.approx(1.0, abs=0.15)
    assert result["pose"]["x"] == pytest.approx(1.0, abs=1e-6)  # the reset, then still
    assert result["pose"]["y"] == pytest.approx(-0.5, abs=1e-6)
    assert "Foxglove control on" in out


def test_one_driver_at_a_time_and_the_base_stops_when_it_vanishes(
        modules: Path, sessions: list[Session], tmp_path: Path) -> None:
    """A second client is refused while the first drives and is told who drives; a NaN
    from the driver stops the base; the driver killed (no goodbye) stops the base at
    once, long before the command timeout (30 s here) would, and the second may drive."""
    s = start(sessions, modules, "drive", "--sim", "--config", config(tmp_path, 30.0),
              "--foxglove-control", "--foxglove", f"127.0.0.1:{free_port()}", "--duration",
              "60", "--json")
    watcher = s.client(SDK)
    watcher.send("subscribe", topic="/twist")

    def commanded(timeout: float = 15.0, where: Any = lambda t: True) -> tuple[float, ...]:
        """The command the base applies (after its limits), as the live view says: the
        first one from now on that is ``where``."""
        watcher.forget("message")
        e = watcher.wait("message", lambda e: e["topic"] == "/twist"
                         and where(twist_of(e, "command")), timeout=timeout)
        return twist_of(e, "command")

    a = s.client(LEGACY)
    a.send("advertise", encoding="json")
    ch_a = a.wait("advertised")["channel"]
    a.send("publish", channel=ch_a, twist=[0.2, 0.0, 0.0], rate_hz=10, seconds=1)
    a.wait("published", timeout=10)
    commanded(where=lambda t: t[0] == pytest.approx(0.2))
    # Its NaN: nothing of it reaches the base, which stops (the timeout is 30 s).
    a.send("publish", channel=ch_a, twist=["NaN", 0.0, 0.0], seconds=0)  # JSON: null
    a.wait("published")
    commanded(where=lambda t: t == (0.0, 0.0, 0.0))
    a.wait("status", lambda e: "linear.x must be a number, got None: the base stops"
           in e["message"])
    a.send("publish", channel=ch_a, twist=[0.2, 0.0, 0.0], rate_hz=10, seconds=1)
    commanded(where=lambda t: t[0] == pytest.approx(0.2))
    a.wait("published", timeout=10)
    nan = b'{"linear": {"x": NaN, "y": 0, "z": 0}, "angular": {"x": 0, "y": 0, "z": 0}}'
    a.send("publish", channel=ch_a, raw=base64.b64encode(nan).decode(), seconds=0)
    a.wait("published")
    commanded(where=lambda t: t == (0.0, 0.0, 0.0))
    a.send("publish", channel=ch_a, twist=[0.2, 0.0, 0.0], rate_hz=10, seconds=8)
    commanded(where=lambda t: t[0] == pytest.approx(0.2))
    # A second would-be driver: refused, told who drives, and nothing of it applies.
    b = s.client(SDK)
    b.send("advertise", encoding="cdr")
    ch_b = b.wait("advertised")["channel"]
    b.send("publish", channel=ch_b, twist=[0.0, 0.0, 1.0], rate_hz=10, seconds=1)
    told = b.wait("status", lambda e: "is driving the base" in e["message"])["message"]
    assert told.startswith("Foxglove client ") and "commands are ignored" in told
    b.wait("published", timeout=10)
    assert commanded() == pytest.approx((0.2, 0.0, 0.0))
    b.send("publish", channel=ch_b, twist=[0.0, "NaN", 0.0], seconds=0)  # CDR: a real NaN
    b.wait("published")
    b.wait("status", lambda e: "linear.y must be finite, got nan: ignored" in e["message"])
    assert commanded() == pytest.approx((0.2, 0.0, 0.0))  # not the driver's: no stop
    # The driver vanishes while driving: the base stops now, not after 30 s.
    a.vanish()
    commanded(timeout=10.0, where=lambda t: t == (0.0, 0.0, 0.0))
    watcher.wait("status", lambda e: "left while driving: the base stopped" in e["message"])
    # and control is free: the second client drives now.
    b.send("publish", channel=ch_b, twist=[0.0, 0.0, 1.0], rate_hz=10, seconds=1)
    commanded(where=lambda t: t[2] == pytest.approx(1.0))
    b.wait("published", timeout=10)
    code, out = s.omnican.finish(timeout=40, interrupt=True)
    assert code == 130, out
    result = json_line(out)
    assert result["true_pose"]["theta"] > 0.3  # the second client's turn happened
    assert result["true_pose"]["x"] > 0.15


@pytest.mark.parametrize("control", [False, True])
def test_a_watch_only_server_moves_nothing(modules: Path, sessions: list[Session],
                                           control: bool) -> None:
    """Without --foxglove-control the server offers no client publish, no services, no
    parameters: a client that tries all of them moves nothing and changes nothing. With
    it, the same client's Twists move the base (so this test can tell)."""
    pytest.importorskip("cyclonedds", reason="needs the ros2 extra: pip install '.[ros2]'")
    args = ["ros2", "--sim", "--localhost", "--domain-id", "96", "--duration", "60",
            "--foxglove", f"127.0.0.1:{free_port()}"]
    s = start(sessions, modules, *args, *(["--foxglove-control"] if control else []))
    c = s.client(SDK)
    assert ("clientPublish" in c.server_info["capabilities"]) is control
    c.send("subscribe", topic="/sim/pose2d")
    c.send("advertise", encoding="json")
    channel = c.wait("advertised")["channel"]
    c.send("publish", channel=channel, twist=[0.3, 0.0, 0.0], rate_hz=10, seconds=2)
    c.wait("published", timeout=10)
    c.send("setParameters", parameters=[{"name": "chassis.max_speed", "value": 0.01}], id="p")
    if control:
        reply = c.wait("parameterValues")
        assert reply["parameters"][0]["value"] == pytest.approx(0.01)
    c.send("close")
    code, out = s.omnican.finish(timeout=60, interrupt=True)
    assert code == 0, out
    true_x = float(next(line for line in out.splitlines()
                        if line.startswith("true pose")).split("x=")[1].split()[0])
    if control:
        assert true_x > 0.3  # 0.3 m/s for about 2 s
    else:
        assert true_x == 0.0  # not a micrometre
        assert not any(e["event"] == "parameterValues" for e in c.events)
        assert not any(e["event"] == "advertiseServices" for e in c.events)


def test_a_stop_from_another_client_holds_until_the_driver_lets_go(
        modules: Path, sessions: list[Session]) -> None:
    """Anyone may call /omnican/stop. From a client that does not drive, it also takes
    control from the driver: the driver's Twists (its Teleop button still held) are
    refused, and it is told why, until it has sent nothing for the command timeout."""
    s = start(sessions, modules, "drive", "--sim", "--foxglove-control", "--foxglove",
              f"127.0.0.1:{free_port()}", "--json")
    watcher = s.client(SDK)
    watcher.send("subscribe", topic="/twist")
    a = s.client(LEGACY)
    a.send("advertise", encoding="json")
    ch = a.wait("advertised")["channel"]
    a.send("publish", channel=ch, twist=[0.2, 0.0, 0.0], rate_hz=10, seconds=5)

    def commands(count: int = 1, where: Any = lambda t: True) -> list[tuple[float, ...]]:
        """The next ``count`` commands the base applies, from the first that is ``where``."""
        watcher.forget("message")
        first = watcher.wait("message", lambda e: e["topic"] == "/twist"
                             and where(twist_of(e, "command")))
        out = [twist_of(first, "command")]
        watcher.forget("message", drain=False)  # the ones skipped on the way came before
        while len(out) < count:
            e = watcher.wait("message", lambda e: e["topic"] == "/twist")
            out.append(twist_of(e, "command"))
        return out

    commands(where=lambda t: t[0] == pytest.approx(0.2))
    watcher.send("call", service="/omnican/stop")
    reply = watcher.wait("response")["data"]
    assert reply["success"] and "drives again once it has let go" in reply["message"]
    # The base stops and stays stopped (25 samples: half a second) while a still sends.

    def a_still_sends() -> bool:
        a._drain()
        return not any(e["event"] == "published" for e in a._unread)

    stopped = commands(26, where=lambda t: t == (0.0, 0.0, 0.0))
    assert a_still_sends(), "the base stopped only once a stopped sending"
    assert stopped == [(0.0, 0.0, 0.0)] * 26
    told = a.wait("status", lambda e: "stopped the base" in e["message"])["message"]
    assert "commands are ignored until it sends none for 0.5 s" in told
    a.wait("published", timeout=15)
    time.sleep(1.0)  # a lets go: silent for longer than the 0.5 s timeout
    a.send("publish", channel=ch, twist=[0.2, 0.0, 0.0], rate_hz=10, seconds=1)
    commands(where=lambda t: t[0] == pytest.approx(0.2))  # and drives again
    a.wait("published", timeout=10)
    code, out = s.omnican.finish(timeout=40, interrupt=True)
    assert code == 130, out
    assert json_line(out)["true_pose"]["x"] > 0.1


def test_teleop_takes_the_teleop_panel_and_its_stop_key_holds(modules: Path) -> None:
    """``omnican teleop --sim --foxglove-control`` in a terminal: a Foxglove client
    drives while the keys are idle and the dashboard says so; a key that would move is
    refused while the client drives; the stop key stops the base and the client, still
    pressing, is told who stopped it; Esc quits and prints where the base went."""
    port = free_port()
    term = terminal.Pty("teleop", "--sim", "--foxglove-control", "--foxglove",
                        f"127.0.0.1:{port}")
    client = None
    try:
        term.wait_for("RUNNING")
        client = NodeClient(modules, f"ws://127.0.0.1:{port}", LEGACY)
        client.connected()
        client.send("advertise", encoding="json")
        ch = client.wait("advertised")["channel"]
        client.send("publish", channel=ch, twist=[0.3, 0.0, 0.0], rate_hz=10, seconds=4)
        term.wait_for_frame("Foxglove client 1 is driving")
        term.keys("i")  # forward, from the keys: refused while the client drives
        term.wait_for_frame("Foxglove client 1 is driving: space stops the base")
        term.keys(" ")
        term.wait_for_frame("stopped Foxglove client 1: it drives again once it lets go")
        told = client.wait("status", lambda e: "stopped the base" in e["message"])["message"]
        assert told.startswith("the terminal's keys stopped the base")
        client.wait("published", timeout=10)
        term.keys("\x1b")
        assert term.exit_code() == 0
        final = term.read(0.5).strip().splitlines()[-1]
        match = re.fullmatch(r"pose x=(\S+) y=(\S+) theta=(\S+)", final.strip())
        assert match is not None, final
        assert float(match[1]) > 0.01  # the client drove it forward (until the stop)
        assert abs(float(match[3])) < 0.01
    finally:
        if client is not None:
            client.close()
        term.close()


APP = "https://app.foxglove.dev"


def test_only_the_foxglove_app_connects_and_only_with_the_token_does_it_drive(
        modules: Path, sessions: list[Session], tmp_path: Path) -> None:
    """``--foxglove-token``: pages other than Foxglove's app are refused at the door (403);
    the app without the token may watch, and its Teleop panel's Twists are refused with
    the reason; the SDK's own port, reachable on loopback past the relay, takes nothing
    from anyone; the app with the token in the URL drives."""
    toml = config(tmp_path, 30.0)
    s = start(sessions, modules, "drive", "--sim", "--config", toml,
              "--foxglove-control", "--foxglove-token", "s3cret", "--foxglove",
              f"127.0.0.1:{free_port()}", "--duration", "12", "--json")
    for page in ("https://evil.example", "null", "http://localhost:8080"):
        evil = s.client(origin=page, query="/?token=s3cret", connect=False)
        assert evil.wait("refused")["status"] == 403
    watcher = s.client(origin=APP)
    watcher.send("advertise", encoding="json")
    ch = watcher.wait("advertised")["channel"]
    watcher.send("publish", channel=ch, twist=[0.0, 0.0, 1.0], rate_hz=10, seconds=1)
    told = watcher.wait("status", lambda e: "may watch, not drive" in e["message"])["message"]
    assert "s3cret" not in told and "?token=" in told
    watcher.send("call", service="/omnican/sim/console", request={"command": "fault 2"})
    assert "may watch, not call" in watcher.wait("failure")["message"]
    watcher.wait("published", timeout=10)
    ports = listening_ports(s.omnican.proc.pid) - {int(s.url.rsplit(":", 1)[1])}
    if ports:  # Linux: the SDK's own port, past the relay
        [inner] = ports
        past = s.client(url=f"ws://127.0.0.1:{inner}", query="/?token=s3cret")
        past.send("advertise", encoding="json")
        ch = past.wait("advertised")["channel"]
        past.send("publish", channel=ch, twist=[0.0, 0.0, 1.0], rate_hz=10, seconds=1)
        past.send("setParameters", parameters=[{"name": "chassis.max_speed", "value": 0.01}],
                  id="p")
        # refused: still the (unlimited) top speed
        assert past.wait("parameterValues")["parameters"][0]["value"] == pytest.approx(
            top_speed(toml))
        past.wait("published", timeout=10)
    driver = s.client(LEGACY, origin=APP, query="/?token=s3cret")
    driver.send("advertise", encoding="cdr")
    ch = driver.wait("advertised")["channel"]
    driver.send("publish", channel=ch, twist=[0.2, 0.0, 0.0], rate_hz=10, seconds=2)
    driver.wait("published", timeout=10)
    code, out = s.omnican.finish(timeout=40)
    assert code == 0, out
    truth = json_line(out)["true_pose"]
    assert truth["x"] > 0.25  # the driver's 0.2 m/s for 2 s
    assert abs(truth["theta"]) < 0.01  # nobody else's turn
    assert "refused: a web page at 'https://evil.example'" in out


def test_abusive_clients_stop_nothing_and_junk_from_the_driver_stops_at_once(
        modules: Path, sessions: list[Session], tmp_path: Path) -> None:
    """While one client drives: a bystander's 16 MB Twist ends the bystander's connection
    and nothing else; 5,000 invalid messages give a few log lines; deep nesting and long
    bad values are refused, quoted short, with no traceback. Then the driver's own deeply
    nested Twist stops the base at once (the command timeout is 30 s)."""
    s = start(sessions, modules, "drive", "--sim", "--config", config(tmp_path, 30.0),
              "--foxglove-control", "--foxglove", f"127.0.0.1:{free_port()}",
              "--duration", "60", "--json")
    watcher = s.client()
    watcher.send("subscribe", topic="/twist")

    def commanded(timeout: float = 15.0, where: Any = lambda t: True) -> tuple[float, ...]:
        watcher.forget("message")
        e = watcher.wait("message", lambda e: e["topic"] == "/twist"
                         and where(twist_of(e, "command")), timeout=timeout)
        return twist_of(e, "command")

    driver = s.client(LEGACY)
    driver.send("advertise", encoding="json")
    ch = driver.wait("advertised")["channel"]
    driver.send("publish", channel=ch, twist=[0.2, 0.0, 0.0], rate_hz=10, seconds=5)
    commanded(where=lambda t: t[0] == pytest.approx(0.2))
    big = s.client()
    big.send("advertise", encoding="json")
    big_ch = big.wait("advertised")["channel"]
    big.send("publish", channel=big_ch, fill="[", size=16_000_000)
    big.wait("close", timeout=30)  # the relay ended its connection
    flood = s.client()  # the SDK answers each with a status, and cuts it off when they pile up
    flood.send("sendText", text="{not json", repeat=2500)
    flood.send("sendText", text=json.dumps({"op": "subscribe", "subscriptions": [
        {"id": 7, "channelId": 99999}]}), repeat=2500)
    flood.wait("sent")
    flood.wait("sent")
    junk = s.client()
    junk.send("advertise", encoding="json")
    junk_ch = junk.wait("advertised")["channel"]
    junk.send("publish", channel=junk_ch, fill="[", size=4000)  # nested too deeply
    junk.send("setParameters", parameters=[{"name": "chassis.max_speed",
                                            "value": "9" * 60_000}], id="long")
    junk.wait("parameterValues", lambda e: e["id"] == "long", timeout=60)
    junk.send("call", service="/omnican/reset_odometry", request={"x": "far" * 1000})
    assert len(junk.wait("response")["data"]["message"]) < 200
    assert commanded() == pytest.approx((0.2, 0.0, 0.0))  # still the driver's
    assert all(len(m) < 300 for m in watcher.statuses())
    # The driver's own junk: the base stops now, not after the 30 s timeout.
    driver.wait("published", timeout=30)
    assert commanded() == pytest.approx((0.2, 0.0, 0.0))  # the last command holds
    driver.send("publish", channel=ch, raw=base64.b64encode(b"[" * 4000).decode(), seconds=0)
    commanded(timeout=10.0, where=lambda t: t == (0.0, 0.0, 0.0))
    code, out = s.omnican.finish(timeout=40, interrupt=True)
    assert code == 130, out
    assert "Traceback" not in out and "Callback failed" not in out
    assert max(len(line) for line in out.splitlines() if not line.startswith("{")) < 400
    mistakes = [line for line in out.splitlines()
                if "Invalid message" in line or "unknown channel" in line]
    assert 1 <= len(mistakes) <= 6, mistakes
    assert "sent a 16000005-byte message (at most 65536): disconnected" in out
