"""The shipped Foxglove layout's plots have data in the demo it ships for (issue 36, item
15): the bus load under --sim (the simulated bus has the config's nominal bitrate), and
what the drives report, which comes in some /wheels messages only: a choice the schema
states, so that a plot reads it as Foxglove's Plot panel does."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from omnican import telemetry
from omnican.cli import main
from omnican.cli.session import SIM_BITRATE
from omnican.telemetry.messages import _SERIES, JSON_SCHEMAS

ROOT = Path(__file__).resolve().parents[2]
LAYOUT = ROOT / "foxglove" / "omnican-layout.json"


def statuses(path: Path) -> list[dict[str, Any]]:
    from mcap.reader import make_reader

    with path.open("rb") as f:
        return [json.loads(msg.data) for _, _, msg in
                make_reader(f).iter_messages(topics=["/status"])]


@pytest.mark.parametrize(("config", "bitrate"), [(None, SIM_BITRATE), ("250000", 250_000)])
def test_the_sim_demo_publishes_the_bus_load(config: str | None, bitrate: int, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """``/status.bus_load``, the layout's bus-load series, under --sim: a share of the
    config's [bus] bitrate (the demo base, which has no config: 500 kbit/s)."""
    pytest.importorskip("mcap")
    argv = ["drive", "--sim", "--fast", "--vx", "0.2", "--duration", "1.5"]
    if config is not None:
        toml = tmp_path / "robot.toml"
        toml.write_text(f'[bus]\ninterface = "socketcan"\nchannel = "can0"\nbitrate = {config}\n'
                        '\n[chassis]\nlayout = "b21"\nbase_radius = 0.19\n\n' +
                        "".join(f"[[wheel]]\nnode_id = {n}\ngear_ratio = 16\nencoder_cpr = "
                                "4096\nwheel_radius = 0.05\n\n" for n in (1, 2, 3)))
        argv += ["--config", str(toml)]
    record = tmp_path / "run.mcap"
    assert main([*argv, "--record", str(record)]) == 0
    capsys.readouterr()
    running = [s for s in statuses(record) if s["state"] == "RUNNING"]
    assert len(running) > 10
    for status in running:
        assert "bus_load" in status, status
        assert status["bus_load"] == pytest.approx(status["bus_bits_per_s"] / bitrate)
        assert 0.0 <= status["bus_load"] < 1.0
    assert running[-1]["bus_load"] > 0.0  # the traffic counted over a window


def _plotted() -> set[tuple[str, str]]:
    """(topic, field) of every series the shipped layout plots on a JSON topic."""
    text = LAYOUT.read_text()
    out = set()
    for topic, path in re.findall(r'"(/[a-z0-9_/]+)\.([A-Za-z0-9_.\[\]]+)"', text):
        if telemetry.TOPICS.get(topic, ("", ""))[1] == telemetry.messages.JSON:
            out.add((topic, re.sub(r"\[\d+\]", "[]", path)))
    return out


def _field(topic: str, path: str) -> dict[str, Any]:
    node = JSON_SCHEMAS[telemetry.TOPICS[topic][0]]
    for part in path.split("."):
        props = node["properties"] if "properties" in node else node["items"]["properties"]
        node = props[part.removesuffix("[]")]
    return node


def test_what_a_drive_reports_is_plotted_as_the_schema_says_it_comes() -> None:
    """Each reading rides on the /wheels messages made while it is fresh and is absent
    from the others: the layout plots every such field per wheel, and the schema says,
    for each, that a plot reads the messages that have it (Foxglove's Plot panel skips a
    message without the path, so the series is drawn through the readings)."""
    plotted = _plotted()
    for field in _SERIES:
        description = _field("/wheels", f"wheels[].{field.name}")["description"]
        assert "a plot of it reads the messages that have it and skips the others" in \
            description, field.name
        assert "no fresh reading of it came" in description, field.name
    shown = {path for topic, path in plotted if topic == "/wheels"}
    assert {f"wheels[].{f.name}" for f in _SERIES if f.plotted} <= shown
    assert "wheels[].temperature_c" in shown
    # every field the layout plots that a message may leave out says when
    for topic, path in plotted:
        field = _field(topic, path)
        if "description" in field:
            assert field["description"].startswith("absent when"), (topic, path)
