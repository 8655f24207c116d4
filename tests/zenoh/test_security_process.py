"""The fleet's credentials across processes, in a network namespace holding only
loopback: an ``omnican zenoh --sim`` base under a base's certificate, alone (listening
on TLS), and hostile processes of raw eclipse-zenoh (no certificate, a viewer's) that
publish cmd_vel and call ~/recover, then an operator's process that drives. And the
refusal of a base that would listen beyond loopback without credentials: one line, exit
2, nothing started. Skipped, with the reason, where no such namespace can be made."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from omnican.zenoh import rmw
from omnican.zenoh.security import Identity
from tests.interop.ros2_interop.harness import NetNs, Proc, clean_env, netns_unavailable
from tests.zenoh.conftest import free_port

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed "
                    "(pip install 'omnican[zenoh]')")
pytest.importorskip("cryptography", reason="cryptography is not installed "
                    "(pip install 'omnican[zenoh-security]')")

TIMEOUT_S = 120.0  # real seconds: a process starting on a loaded machine

#: A member of the network as a process of raw eclipse-zenoh: it links (or fails to),
#: sends cmd_vel for a while, calls services, and says each outcome as a JSON line.
PEER = r'''
import json, struct, sys, time, zenoh
args = json.loads(sys.argv[1])
def say(**what):
    print(json.dumps(what), flush=True)
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5("listen/endpoints", "[]")
conf.insert_json5("connect/endpoints", json.dumps([args["endpoint"]]))
for path, value in args["tls"]:
    conf.insert_json5(path, value)
try:
    session = zenoh.open(conf)
except zenoh.ZError as exc:
    say(event="refused", error=str(exc))
    sys.exit(0)
gid = bytes.fromhex(args["gid"])
def attachment(seq):
    return struct.pack("<qq", seq, time.time_ns()) + bytes((16,)) + gid
def ask(key):
    replies = [r for r in session.get(key, payload=b"\x00\x01\x00\x00\x00",
                                      attachment=attachment(1), timeout=3.0)]
    return [r.ok.payload.to_bytes()[12:-1].decode() for r in replies if r.ok is not None]
for step in args["steps"]:
    if step[0] == "drive":
        pub = session.declare_publisher(args["cmd_vel"])
        end, seq = time.monotonic() + step[1], 0
        while time.monotonic() < end:
            seq += 1
            pub.put(bytes.fromhex(args["twist"]), attachment=attachment(seq))
            time.sleep(0.05)
        say(event="sent", samples=seq)
    else:
        say(event="answer", service=step[0], replies=ask(args["services"][step[0]]))
session.close()
'''


@pytest.fixture(scope="module")
def netns() -> Iterator[NetNs]:
    why = netns_unavailable()
    if why is not None:
        pytest.skip(why)
    with NetNs() as ns:
        yield ns


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from omnican.zenoh.credentials import make

    root = tmp_path_factory.mktemp("fleet") / "fleet"
    make(root, [Identity("base", "robot1"), Identity("operator", "alice"),
                Identity("viewer", "bob"), Identity("router", "router")])
    return root


def omnican(ns: NetNs, *argv: str) -> Proc:
    return Proc(ns.wrap([sys.executable, "-m", "omnican", *argv]), env=clean_env())


def peer(ns: NetNs, root: Path, who: str | None, endpoint: str, steps: list[list[object]],
         tmp_path: Path) -> list[dict[str, object]]:
    """Run :data:`PEER` as ``who`` (None: TLS without a certificate of its own) to the
    end; its JSON lines."""
    from omnican.telemetry import cdr
    from omnican.zenoh.security import tls_entries
    from omnican.zenoh.services import service_key

    node = rmw.RosNode(0, "0", 0, "omnican", namespace="/robot1")
    if who is None:
        tls = [("transport/link/tls", json.dumps({
            "root_ca_certificate": str(root / "ca.pem"), "enable_mtls": True,
            "verify_name_on_connect": False}))]
    else:
        folder = root / Identity.parse(who).folder
        tls = tls_entries(str(root / "ca.pem"), str(folder / "cert.pem"),
                          str(folder / "key.pem"))
    twist = cdr.encode("geometry_msgs/msg/Twist", {"linear": {"x": 0.2, "y": 0.0, "z": 0.0},
                                                   "angular": {"x": 0.0, "y": 0.0, "z": 0.0}})
    args = {"endpoint": endpoint, "tls": tls, "gid": (who or "none").encode().hex()[:32]
            .ljust(32, "0"), "twist": twist.hex(), "steps": steps,
            "cmd_vel": rmw.data_key(0, "/robot1/cmd_vel", "geometry_msgs/msg/Twist",
                                    rmw.type_hash("geometry_msgs/msg/Twist")),
            "services": {name: service_key(node, name) for name in ("stop", "recover")}}
    script = tmp_path / "peer.py"
    script.write_text(PEER)
    done = subprocess.run(ns.wrap([sys.executable, str(script), json.dumps(args)]),
                          capture_output=True, text=True, timeout=TIMEOUT_S, env=clean_env(),
                          check=False)
    assert done.returncode == 0, done.stderr
    return [json.loads(line) for line in done.stdout.splitlines()]


def true_x(base: Proc) -> float:
    base.send("pose")
    line = base.read_until(lambda text: text.startswith("true pose x="), TIMEOUT_S)
    assert line is not None, base.lines[-5:]
    return float(line.split()[2].removeprefix("x="))


def test_only_an_operator_drives_a_base_alone(netns: NetNs, fleet: Path,
                                              tmp_path: Path) -> None:
    endpoint = f"tls/127.0.0.1:{free_port()}"
    base = omnican(netns, "zenoh", "--sim", "--zenoh-credentials", str(fleet),
                   "--zenoh-identity", "base/robot1", "--namespace", "/robot1",
                   "--zenoh-listen", endpoint)
    try:
        started = base.read_until(lambda text: text == "Ctrl-C to stop", TIMEOUT_S)
        assert started is not None, "\n".join(base.lines)
        assert "mTLS as base/robot1" in base.lines[0]
        # no certificate: no link, over plain TCP or over TLS
        for who, at in ((None, endpoint), ("operator/alice", endpoint.replace("tls/", "tcp/"))):
            said = peer(netns, fleet, who, at, [["drive", 0.5]], tmp_path)
            assert [s["event"] for s in said] == ["refused"], said
        # a viewer: its cmd_vel and its recover do nothing; its stop, sent after them on
        # the same link, is answered
        said = peer(netns, fleet, "viewer/bob", endpoint,
                    [["drive", 2.0], ["recover"], ["stop"]], tmp_path)
        assert said[0]["event"] == "sent" and int(str(said[0]["samples"])) > 10, said
        assert said[1] == {"event": "answer", "service": "recover", "replies": []}, said
        assert said[2] == {"event": "answer", "service": "stop",
                           "replies": ["stopped: held until recover"]}, said
        assert true_x(base) == 0.0
        # an operator recovers the viewer's stop and drives
        said = peer(netns, fleet, "operator/alice", endpoint,
                    [["recover"], ["drive", 3.0]], tmp_path)
        assert said[0]["replies"] == ["recovered"], said
        assert true_x(base) > 0.05
        base.send("quit")
        code, out = base.finish(timeout=TIMEOUT_S)
        assert code == 0, out
    finally:
        base.kill()


@pytest.mark.parametrize("argv", [
    ["zenoh", "--sim", "--zenoh-listen", "tcp/0.0.0.0:{port}"],
    ["zenoh", "--sim", "--zenoh-listen", "tcp/[::]:0", "--zenoh-mode", "client"],
    ["drive", "--sim", "--duration", "1", "--zenoh", "--zenoh-listen", "tcp/0.0.0.0:{port}"],
    ["fleet", "--router", "--once", "--zenoh-listen", "tcp/0.0.0.0:{port}"],
], ids=["zenoh", "client", "drive --zenoh", "fleet --router"])
def test_listening_beyond_loopback_without_credentials_is_refused(
        netns: NetNs, argv: list[str]) -> None:
    """One line that says who could then drive the robot, exit 2, nothing started (no
    startup line, no drive)."""
    port = free_port()
    proc = omnican(netns, *[a.format(port=port) for a in argv])
    try:
        code, out = proc.finish(timeout=TIMEOUT_S)
    finally:
        proc.kill()
    lines = out.splitlines()
    assert code == 2, out
    assert len(lines) == 1, out
    assert re.match(r"omnican: error: (command line: )?zenoh: would listen on tcp/", lines[0]), out
    assert "without credentials: anyone who can reach it could drive" in lines[0]
    assert "--zenoh-allow-insecure" in lines[0]


def test_a_missing_zenoh_config_is_named(netns: NetNs, tmp_path: Path) -> None:
    missing = tmp_path / "zenoh.json5"
    proc = omnican(netns, "zenoh", "--sim", "--duration", "1", "--zenoh-config", str(missing))
    try:
        code, out = proc.finish(timeout=TIMEOUT_S)
    finally:
        proc.kill()
    assert (code, out) == (2, f"omnican: error: Zenoh config {missing}: no such file"), out
