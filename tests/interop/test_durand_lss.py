"""omnican commission against an LSS slave nobody here wrote: durand's (a CiA 301
responder on python-can, PyPI), three nodes without a node id (FFh) of one vendor and
product on python-can's virtual bus (issue 38).

What durand's slave covers here: switch state global, fast scan (CiA 305, bit by bit),
configure node id, configure bit timing, store configuration (through its store
callback, or "not supported" without one), inquire node id, taking the new id on leaving
the configuration state (its boot-up), and its SDO server answering 1018h at the new id.
What it does not: its LSS slave answers selective switching only in the waiting state and
inquiries only in configuration, has no 1010h/1011h (store parameters), and keeps nothing
across a restart of its own (the store callback is where a device would write its memory):
the power cycle and stored parameters are checked against the simulator
(tests/cli/test_commission.py)."""

from __future__ import annotations

import contextlib
import io
import threading
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from omnican.cli import main

durand = pytest.importorskip("durand")
from durand import CANBusNetwork, Node  # noqa: E402
from durand.scheduler import SyncScheduler, get_scheduler, set_scheduler  # noqa: E402

VENDOR, PRODUCT, REVISION = 0x0000_0A1B, 0x0000_0402, 0x0001_0000


@contextlib.contextmanager
def durand_nodes(channel: str, serials: list[int], store: bool = True
                 ) -> Iterator[list[tuple[Node, list[tuple[int | None, int]]]]]:
    """A durand node without a node id per serial, each on a bus of its own on
    ``channel``, with what its store callback was given ((bit/s, node id) each time)."""
    old = get_scheduler()
    scheduler = SyncScheduler()
    thread = threading.Thread(target=scheduler.run, name="durand-scheduler", daemon=True)
    set_scheduler(scheduler)
    thread.start()
    buses, networks, nodes = [], [], []
    try:
        for serial in serials:
            bus = can.Bus(interface="virtual", channel=channel)
            buses.append(bus)
            network = CANBusNetwork(bus)
            networks.append(network)
            node = Node(network, 0xFF)
            od = node.object_dictionary
            for sub, value in ((1, VENDOR), (2, PRODUCT), (3, REVISION), (4, serial)):
                od.write(0x1018, sub, value)
            stored: list[tuple[int | None, int]] = []
            if store:
                node.lss.set_store_configuration_callback(
                    lambda rate, node_id, stored=stored: stored.append((rate, node_id)))
            node.lss.set_baudrate_change_callback(lambda rate, delay: None)
            nodes.append((node, stored))
        yield nodes
    finally:
        for network in networks:
            network.stop()
        for bus in buses:
            bus.shutdown()
        scheduler.stop()
        thread.join(5)
        set_scheduler(old)


def robot_toml(tmp_path: Path, serials: dict[int, int]) -> Path:
    wheels = "".join(f"[[wheel]]\nnode_id = {n}\nserial = {s}\nvelocity_scale = -4772.44\n"
                     "position_scale = 48000.0\n\n" for n, s in serials.items())
    toml = tmp_path / "robot.toml"
    toml.write_text(f'[chassis]\nlayout = "b21"\nbase_radius = 0.19\n\n{wheels}')
    return toml


def commission(toml: Path, channel: str, *more: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["commission", str(toml), "-i", "virtual", "-c", channel,
                     "--lss-timeout", "0.1", *more])
    return code, out.getvalue(), err.getvalue()


def test_three_durand_nodes_without_ids_get_the_configs_ids_and_bit_rate(
        tmp_path: Path, channel: str) -> None:
    toml = robot_toml(tmp_path, {1: 9003, 2: 9001, 3: 9002})
    with durand_nodes(channel, [9001, 9002, 9003]) as nodes:
        code, out, err = commission(toml, channel, "--new-bitrate", "250000")
        assert code == 0, err
        assert [node.node_id for node, _ in nodes] == [2, 3, 1]
        assert [stored for _, stored in nodes] == [[(250_000, 2)], [(250_000, 3)],
                                                   [(250_000, 1)]]
        assert "bit rate 250000 bit/s stored" in out
        for serial, node_id in ((9001, "2"), (9002, "3"), (9003, "1")):
            assert any(line.split("│")[1].strip() == f"0x{serial:08X}"
                       and line.split("│")[4].strip() == node_id
                       for line in out.splitlines() if line.count("│") == 7), out


def test_a_durand_node_that_cannot_store_is_named(tmp_path: Path, channel: str) -> None:
    toml = robot_toml(tmp_path, {1: 9101, 2: 9102, 3: 9103})
    with durand_nodes(channel, [9101], store=False) as nodes:
        code, out, err = commission(toml, channel)
    assert code == 1
    assert ("omnican: error: the drive with serial 0x0000238D refused to store node id 1 (LSS error "
            "1: store not supported)") in err
    assert nodes[0][0].node_id == 1  # it runs with it until its power goes
    assert "NOT STORED" in out
    assert "no drive with serial 0x0000238E (node 2 in the config) answered" in err
