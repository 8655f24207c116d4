"""A user's ``CYCLONEDDS_URI`` beside omnican's own network settings: Cyclone adds list
entries up rather than overriding them, so an interface named by both is selected twice
(Cyclone refuses to start) and a user's other interface or peer would widen ``--sim``'s
loopback-only network. omnican's choice replaces the user's interfaces and peers; the
rest of the user's configuration stays.

First the configuration string itself (no DDS); then ``omnican ros2`` with the real
Cyclone DDS, each run inside a private network namespace that has only loopback (and,
for the case of a user file naming ``eth0``, a bridge without ports named ``eth0`` whose
only address is 127.0.0.2: nothing can leave it, and the test asserts that DDS selects
loopback only). Where no such namespace can be made, those tests skip. DDS is never run
on the stand-in eth0 on purpose: that the interface a user and the command line both
name is named once is checked on the configuration alone.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from xml.etree import ElementTree

import pytest

from omnican.ros2.settings import Ros2Settings, cyclone_config, split_cyclone_uri
from tests.interop.ros2_interop.harness import NetNs, clean_env, netns_unavailable

ROOT = Path(__file__).resolve().parents[2]
NS = 'xmlns="https://cdds.io/config" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"'


def user_file(tmp_path: Path, general: str, rest: str = "", name: str = "user.xml") -> Path:
    """A Cyclone configuration file as ROS 2 set-ups write them (namespace, declaration)."""
    path = tmp_path / name
    path.write_text(f'<?xml version="1.0" encoding="UTF-8"?>\n<CycloneDDS {NS}>\n'
                    f'  <Domain Id="any">\n    <General>{general}</General>\n{rest}'
                    "  </Domain>\n</CycloneDDS>\n")
    return path


LO = '<Interfaces><NetworkInterface name="lo"/></Interfaces><AllowMulticast>false</AllowMulticast>'
ETH0 = '<Interfaces><NetworkInterface name="eth0" priority="default"/></Interfaces>'
KEEP = '    <Internal><SocketReceiveBufferSize min="1MB"/></Internal>\n'


def read_text(path: str) -> str:
    return Path(path).read_text()


def parts(config: str) -> list[ElementTree.Element]:
    """Every fragment of a configuration string, parsed (files read)."""
    out = []
    for item, is_xml in split_cyclone_uri(config):
        text = item if is_xml else read_text(item.removeprefix("file://"))
        out.append(ElementTree.fromstring(text))
    return out


def local(tag: str) -> str:
    return tag.rpartition("}")[2]


def named(config: str, tag: str, attribute: str) -> list[str]:
    """The ``attribute`` of every ``tag`` element across the fragments of ``config``."""
    return [e.get(attribute, "") for root in parts(config) for e in root.iter()
            if local(e.tag) == tag]


# ---------------------------------------------------------------- the configuration


def test_a_loopback_user_file_and_sim_name_lo_once(tmp_path: Path) -> None:
    path = user_file(tmp_path, LO, KEEP)
    config = cyclone_config(Ros2Settings().with_loopback(), f"file://{path}", read_text)
    assert named(config, "NetworkInterface", "name") == ["lo"]
    # The user's other settings stay, before omnican's network part.
    assert named(config, "SocketReceiveBufferSize", "min") == ["1MB"]
    assert [local(r[0][0].tag) for r in parts(config)] == ["Compatibility", "General",
                                                            "General"]


def test_the_same_interface_from_user_and_command_line_is_named_once(tmp_path: Path) -> None:
    path = user_file(tmp_path, ETH0)
    config = cyclone_config(Ros2Settings(interface="eth0"), str(path), read_text)
    assert named(config, "NetworkInterface", "name") == ["eth0"]


def test_sim_keeps_to_loopback_whatever_the_user_file_names(tmp_path: Path) -> None:
    path = user_file(tmp_path, ETH0 + "<NetworkInterfaceAddress>wlan0</NetworkInterfaceAddress>",
                     '    <Discovery><Peers><Peer address="nav.example"/></Peers></Discovery>\n'
                     + KEEP)
    config = cyclone_config(Ros2Settings().with_loopback(), f"file://{path}", read_text)
    assert named(config, "NetworkInterface", "name") == ["lo"]
    assert named(config, "NetworkInterfaceAddress", "name") == []
    assert named(config, "Peer", "address") == ["127.0.0.1"]
    assert named(config, "SocketReceiveBufferSize", "min") == ["1MB"]


def test_inline_xml_and_several_items(tmp_path: Path) -> None:
    path = user_file(tmp_path, ETH0, KEEP)
    inline = ("<CycloneDDS><Domain><General><Interfaces><NetworkInterface name='lo'/>"
              "</Interfaces></General><Tracing><Verbosity>warning</Verbosity></Tracing>"
              "<!-- a comment, with a comma --></Domain></CycloneDDS>")
    uri = f" {inline} , file://{path},"
    assert [is_xml for _, is_xml in split_cyclone_uri(uri)] == [True, False]
    config = cyclone_config(Ros2Settings(interface="lo"), uri, read_text)
    assert named(config, "NetworkInterface", "name") == ["lo"]
    assert named(config, "SocketReceiveBufferSize", "min") == ["1MB"]
    assert [e.text for r in parts(config) for e in r.iter() if e.tag == "Verbosity"] == \
        ["warning"]


def test_what_omnican_does_not_set_is_the_users(tmp_path: Path) -> None:
    """Without an interface or peers of omnican's, the user's list goes as it is, files
    unread; an unreadable or broken file is left for Cyclone to report."""
    path = user_file(tmp_path, ETH0)
    uri = f"file://{path}"
    assert cyclone_config(Ros2Settings(), uri, read_text).split(",")[1] == uri
    assert cyclone_config(Ros2Settings(multicast=False), uri,
                          read_text).split(",")[1] == uri
    broken = tmp_path / "broken.xml"
    broken.write_text("<CycloneDDS><Domain>")
    lo = Ros2Settings().with_loopback()
    for item in (str(tmp_path / "missing.xml"), str(broken)):
        assert cyclone_config(lo, item, read_text).split(",")[1] == item


# ---------------------------------------------------------------- with Cyclone DDS


@pytest.fixture
def netns() -> Iterator[NetNs]:
    pytest.importorskip("cyclonedds", reason="needs the ros2 extra: pip install '.[ros2]'")
    why = netns_unavailable()
    if why:
        pytest.skip(why)
    with NetNs() as ns:
        yield ns


def with_eth0(netns: NetNs) -> None:
    """An interface named eth0 in the namespace that leads nowhere: a bridge without
    ports, whose only address is on the loopback range."""
    made = subprocess.run(netns.wrap(["sh", "-c", "ip link add eth0 type bridge && ip addr "
                                      "add 127.0.0.2/32 dev eth0 && ip link set eth0 up"]),
                          capture_output=True, text=True, check=False)
    if made.returncode != 0:
        pytest.skip(f"cannot make a stand-in eth0 in the namespace: {made.stderr.strip()}")


def ros2(netns: NetNs, uri: str, *args: str) -> subprocess.CompletedProcess[str]:
    env = clean_env(CYCLONEDDS_URI=uri, PYTHONPATH=str(ROOT))
    return subprocess.run(netns.wrap([sys.executable, "-m", "omnican", "ros2", "--sim",
                                      "--duration", "1", *args]),
                          capture_output=True, text=True, env=env, timeout=120,
                          stdin=subprocess.DEVNULL, check=False)


def started(run: subprocess.CompletedProcess[str], network: str) -> None:
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith(f"ROS 2 node /omnican on DDS domain 0 ({network})"), run.stdout
    assert "drives disabled" in run.stdout


def test_ros2_sim_starts_with_a_loopback_cyclonedds_uri(netns: NetNs, tmp_path: Path) -> None:
    path = user_file(tmp_path, LO, KEEP)
    started(ros2(netns, f"file://{path}"), "loopback only")
    inline = "<CycloneDDS><Domain><General>" + LO + "</General></Domain></CycloneDDS>"
    started(ros2(netns, inline), "loopback only")


def test_a_user_file_naming_eth0_does_not_widen_sim(netns: NetNs, tmp_path: Path) -> None:
    """Cyclone's own trace: the only interface selected is lo, the only peer 127.0.0.1."""
    with_eth0(netns)
    trace = tmp_path / "cyclone.log"
    path = user_file(tmp_path, ETH0, '    <Discovery><Peers><Peer address="127.0.0.3"/>'
                     "</Peers></Discovery>\n    <Tracing><Verbosity>config</Verbosity>"
                     f"<OutputFile>{trace}</OutputFile></Tracing>\n")
    started(ros2(netns, f"file://{path}"), "loopback only")
    text = trace.read_text()
    selected = [line.partition("selected interfaces: ")[2] for line in text.splitlines()
                if "selected interfaces: " in line]
    assert selected and all(s.startswith("lo ") and "eth0" not in s for s in selected), text
    peers = [line.rpartition(": ")[2].split()[0] for line in text.splitlines()
             if "Discovery/Peers/Peer[@Address]" in line]
    assert peers == ["127.0.0.1"], text
    assert os.path.getsize(trace) > 0
