"""The [zenoh] table of a robot config: parsed, checked (one line naming the key), its
defaults the Zenoh front end's, and the command line's flags winning over it."""

from __future__ import annotations

import contextlib
import io
import sys
from dataclasses import fields
from pathlib import Path

import pytest

from omnican.config import SCHEMA, load_config
from omnican.errors import ConfigError
from omnican.zenoh.settings import GRAPH_KEYS, ZenohSettings, from_table
from omnican.zenoh.table import ZENOH_RATES, ZenohTable
from tests.support.helpers import one_error_line

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "robot.toml"


def config(tmp_path: Path, table: str) -> Path:
    path = tmp_path / "robot.toml"
    path.write_text(EXAMPLE.read_text() + "\n[zenoh]\n" + table)
    return path


def run_main(argv: list[str]) -> tuple[int, str, str]:
    from omnican.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse's own errors
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


def test_the_table_is_parsed_with_its_paths_made_whole(tmp_path: Path) -> None:
    cfg = load_config(config(tmp_path, (
        'enabled = true\ndomain_id = 7\nnamespace = "/robot1"\nnode_name = "base"\n'
        'mode = "client"\nconnect = ["tcp/127.0.0.1:7447"]\nlisten = ["tcp/127.0.0.1:0"]\n'
        'multicast = true\nconfig_file = "zenoh.json5"\ncmd_vel_stamped = true\n'
        "odom_rate_hz = 20\nsummary_rate_hz = 0.5\n")))
    t = cfg.front_ends.get("zenoh")
    assert t is not None and t.enabled and t.domain_id == 7 and t.mode == "client"
    assert t.connect == ("tcp/127.0.0.1:7447",) and t.listen == ("tcp/127.0.0.1:0",)
    assert t.config_file == str(tmp_path.resolve() / "zenoh.json5")
    assert t.odom_rate_hz == 20.0 and isinstance(t.odom_rate_hz, float)
    assert "namespace" in t.given and "status_rate_hz" not in t.given
    s = from_table(t)
    assert (s.domain_id, s.namespace, s.node_name, s.multicast, s.cmd_vel_stamped) == \
        (7, "/robot1", "base", True, True)
    assert s.rates_hz == {"/odom": 20.0, "/joint_states": 50.0, "/battery_state": 1.0,
                          "/status": 10.0, "/wheels": 10.0, "/base_summary": 0.5}


def test_no_table_and_an_empty_one_are_the_front_ends_defaults(tmp_path: Path) -> None:
    """ZenohTable's fields are the schema's keys, their defaults the schema's; settings
    made of an empty table are ZenohSettings' own defaults."""
    names = {f.name for f in fields(ZenohTable)} - {"given", "connect", "listen"}
    assert names | {"connect", "listen"} == set(SCHEMA["zenoh"])
    for name in names:
        assert getattr(ZenohTable(), name) == SCHEMA["zenoh"][name].default, name
    assert set(ZENOH_RATES) <= set(SCHEMA["zenoh"])
    cfg = load_config(config(tmp_path, ""))
    assert cfg.front_ends["zenoh"] == ZenohTable()
    assert from_table(cfg.front_ends["zenoh"]) == from_table(None) == ZenohSettings()


@pytest.mark.parametrize(("table", "words"), [
    ("domain_id = 300", "zenoh.domain_id: must be 0-232, got 300"),
    ("odom_rate_hz = 0", "zenoh.odom_rate_hz: must be 0.01-1000, got 0"),
    ("summary_rate_hz = 2000.0", "zenoh.summary_rate_hz: must be 0.01-1000, got 2000"),
    ("wheels_rate_hz = nan", "zenoh.wheels_rate_hz: must be a number, got nan"),
    ('mode = "router"', "zenoh.mode: must be one of peer, client, got 'router'"),
    ('connect = "tcp/127.0.0.1:7447"', "zenoh.connect: must be list"),
    ("listen = [7447]", "zenoh.listen: must be an array of endpoints"),
    ("multicast = 1", "zenoh.multicast: must be bool"),
    ("nodename = 'x'", "zenoh.nodename: unknown key 'nodename' (did you mean 'node_name'?)"),
])
def test_a_bad_value_is_one_line_naming_the_key(tmp_path: Path, table: str,
                                                words: str) -> None:
    path = config(tmp_path, table + "\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value).startswith(f"{path}: {words}"), str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(("table", "words"), [
    ('namespace = "/robot 1"', "zenoh: namespace '/robot 1' is not a ROS 2 namespace"),
    ('node_name = "9lives"', "zenoh: node name '9lives' is not a ROS 2 name"),
    ('connect = ["127.0.0.1:7447"]', "zenoh: '127.0.0.1:7447' is not a Zenoh endpoint"),
])
def test_check_config_says_what_the_front_end_would(tmp_path: Path, table: str,
                                                    words: str) -> None:
    """Names and endpoints are the front end's to check: check-config (and every
    command that loads the config) refuses them in one line naming the file."""
    path = config(tmp_path, table + "\n")
    code, _, err = run_main(["check-config", str(path)])
    assert code == 2
    line = one_error_line(err)
    assert str(path) in line and words in line, line
    code, _, err = run_main(["drive", "--sim", "--config", str(path), "--vx", "0.1"])
    assert code == 2 and words in one_error_line(err)


def _args(argv: list[str]) -> object:
    from omnican.cli import build_parser

    return build_parser(argv[0]).parse_args(argv)


def test_the_flags_win_over_the_table(tmp_path: Path) -> None:
    from omnican.zenoh.arguments import settings_from

    cfg = load_config(config(tmp_path, (
        'namespace = "/table"\ndomain_id = 3\nmode = "client"\n'
        'connect = ["tcp/127.0.0.1:7000"]\nmulticast = true\nodom_rate_hz = 10\n')))
    table = settings_from(_args(["drive", "--vx", "0.1"]), cfg)  # type: ignore[arg-type]
    assert (table.namespace, table.domain_id, table.mode, table.connect, table.multicast) \
        == ("/table", 3, "client", ("tcp/127.0.0.1:7000",), True)
    flags = settings_from(_args(  # type: ignore[arg-type]
        ["drive", "--vx", "0.1", "--namespace", "/flag", "--domain-id", "4",
         "--zenoh-mode", "peer", "--zenoh-connect", "tcp/127.0.0.1:7001",
         "--no-zenoh-multicast", "--cmd-vel-stamped"]), cfg)
    assert (flags.namespace, flags.domain_id, flags.mode, flags.connect, flags.multicast,
            flags.cmd_vel_stamped) == ("/flag", 4, "peer", ("tcp/127.0.0.1:7001",), False,
                                       True)
    assert flags.rates_hz["/odom"] == 10.0  # no flag: the table's


def test_under_ros2_the_graph_is_the_ros2_nodes_unless_the_table_or_a_flag_says(
        tmp_path: Path) -> None:
    from omnican.zenoh.arguments import settings_from

    graph = {"namespace": "/ros", "node_name": "ros_node", "domain_id": 9,
             "cmd_vel_stamped": True}
    assert set(graph) == set(GRAPH_KEYS)
    cfg = load_config(config(tmp_path, 'node_name = "zenoh_node"\n'))
    s = settings_from(_args(["ros2"]), cfg, graph)  # type: ignore[arg-type]
    assert (s.namespace, s.node_name, s.domain_id, s.cmd_vel_stamped) == \
        ("/ros", "zenoh_node", 9, True)
    s = settings_from(_args(["ros2", "--node-name", "flag"]), cfg, graph)  # type: ignore[arg-type]
    assert s.node_name == "flag"


@pytest.mark.parametrize(("argv", "table", "on"), [
    ([], "", False),
    (["--zenoh"], "", True),
    ([], "enabled = true\n", True),
    (["--no-zenoh"], "enabled = true\n", False),
    (["--zenoh-connect", "tcp/127.0.0.1:7447"], "", True),
])
def test_what_turns_the_front_end_on(tmp_path: Path, argv: list[str], table: str,
                                     on: bool) -> None:
    pytest.importorskip("zenoh")
    from omnican.zenoh.arguments import front_end_settings

    cfg = load_config(config(tmp_path, table))
    got = front_end_settings(_args(["drive", "--vx", "0.1", *argv]), cfg)  # type: ignore[arg-type]
    assert (got is not None) is on


def test_no_zenoh_with_a_zenoh_flag_is_a_usage_error() -> None:
    code, _, err = run_main(["drive", "--sim", "--vx", "0.1", "--no-zenoh",
                             "--zenoh-connect", "tcp/127.0.0.1:7447"])
    assert code == 2
    assert one_error_line(err).endswith("--zenoh-connect is for the Zenoh front end: drop "
                                        "--no-zenoh")


def test_a_missing_zenoh_config_file_is_one_line_before_the_drives_come_up(
        tmp_path: Path) -> None:
    pytest.importorskip("zenoh")
    code, out, err = run_main(["drive", "--sim", "--vx", "0.1", "--zenoh",
                               "--zenoh-config", str(tmp_path / "none.json5")])
    assert code == 2 and out == ""
    assert one_error_line(err).endswith(f"Zenoh config {tmp_path / 'none.json5'}: no such file")


@pytest.mark.parametrize("argv", [
    ["drive", "--sim", "--vx", "0.1", "--zenoh"],
    ["sim", "--zenoh", "--duration", "0.1"],
    ["ros2", "--sim", "--localhost", "--zenoh", "--duration", "0.1"],
])
def test_zenoh_without_the_extra_is_one_line_naming_it(monkeypatch: pytest.MonkeyPatch,
                                                       argv: list[str]) -> None:
    from omnican.extras import install_hint

    if argv[0] == "ros2":
        pytest.importorskip("cyclonedds")
    monkeypatch.setitem(sys.modules, "zenoh", None)
    code, out, err = run_main(argv)
    assert code == 2
    line = one_error_line(err)
    assert "--zenoh" in line and install_hint("zenoh") in line, line
    assert "serving" not in out  # nothing came up
