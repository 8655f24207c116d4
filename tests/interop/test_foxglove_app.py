"""What Foxglove's own app makes of the live view and the shipped layout.

The app's code comes from its web build (``@foxglove/studio-base`` on npm: the open-source
Foxglove Studio, which Lichtblick forked), run on Node.js by tests/interop/foxglove_node/app/
app.cjs: its ``parseChannel`` (the JSON schema parser and the ROS 2 reader behind "Failed
to parse channel schema") on every channel the live view advertises, with a message of
each; and the schemas its 3D panel subscribes to, against the topics the layout gives that
panel. Installed once into ~/.cache/omnican/foxglove-node (a 36 MB package); those tests
are skipped, with the reason, where Node.js or npm is missing or npm cannot be reached.

The layout's geometry and series are checked here against the numbers the app's panels
use (quoted from the same build), without Node.
"""

from __future__ import annotations

import base64
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from omnican.telemetry import messages as m
from tests.interop.foxglove_node.harness import HERE as NODE_DIR
from tests.interop.foxglove_node.harness import node_modules
from tests.support.foxglove_client import FoxgloveClient
from tests.support.helpers import drive_for, lockstep_rig, with_truth

ROOT = Path(__file__).resolve().parents[2]
LAYOUT = json.loads((ROOT / "foxglove" / "omnican-layout.json").read_text())
CONFIGS: dict[str, dict[str, Any]] = LAYOUT["configById"]
APP = NODE_DIR / "app"


@pytest.fixture(scope="module")
def app_modules() -> Path:
    path, note = node_modules(APP)
    if path is None:
        pytest.skip(note)
    print(f"Foxglove app code: {note}")
    return path


def run_app(modules: Path, mode: str, given: Any = None) -> Any:
    done = subprocess.run(["node", str(APP / "app.cjs"), mode],
                          input=json.dumps(given) if given is not None else "",
                          capture_output=True, text=True, timeout=120, check=False,
                          env={**os.environ, "NODE_PATH": str(modules)})
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_the_app_parses_every_channel_of_the_live_view_and_decodes_its_messages(
        app_modules: Path, channel: str) -> None:
    """Every channel a simulated base's live view advertises goes through the app's
    parseChannel as the app's WebSocket player builds it, and a message of each decodes
    to what omnican sent: nothing lands in the app's Problems tab, no panel stays empty."""
    pytest.importorskip("foxglove")
    from omnican.live import watch

    expected = {*m.TOPICS, m.CAN_RX, m.CAN_TX, "/can/TPDO2_node1"}
    first: dict[str, bytes] = {}
    with lockstep_rig(channel) as (_, sim, base), with_truth(base, sim), \
            watch(base, sim, "127.0.0.1:0") as view:
        assert view is not None
        client = FoxgloveClient(view.url)
        try:
            client.wait_for_topics(expected)
            client.subscribe(sorted(expected))
            stop = threading.Event()

            def read() -> None:
                while not stop.is_set():
                    for topic, _, payload in client.messages(timeout=0.1):
                        first.setdefault(topic, payload)

            reader = threading.Thread(target=read, name="test-foxglove-app-reader")
            reader.start()
            try:
                deadline = time.monotonic() + 60.0  # a bound on a stuck run, not a figure
                while set(first) != expected and time.monotonic() < deadline:
                    drive_for(base, 0.2, vx=0.2, wz=0.5)
            finally:
                stop.set()
                reader.join()
            channels = [client.channels[t] for t in sorted(expected)]
        finally:
            client.close()
    assert set(first) == expected, f"no message on {sorted(expected - set(first))}"
    given = [{"topic": ch["topic"], "encoding": ch["encoding"], "schemaName": ch["schemaName"],
              "schema": ch["schema"], "schemaEncoding": ch.get("schemaEncoding") or (
                  "jsonschema" if ch["encoding"] == "json" else ""),
              "message": base64.b64encode(first[ch["topic"]]).decode()} for ch in channels]
    seen = run_app(app_modules, "channels", given)
    problems = {t: r["error"] for t, r in seen.items() if "error" in r}
    assert problems == {}, problems
    # The JSON topics: what the app reads is what was sent, field by field; a reading the
    # virtual bus cannot give (its load: no bitrate) is absent, not -1.
    for topic in ("/wheels", "/status", "/pose2d", "/twist", "/sim/pose2d", "/can/TPDO2_node1"):
        assert seen[topic]["decoded"] == json.loads(first[topic]), topic
    assert "bus_load" not in seen["/status"]["decoded"]
    # The 3D panel's topics decode to the pose and the path so far.
    from omnican.telemetry import cdr

    pose = cdr.decode("geometry_msgs/msg/PoseStamped", first["/odom/pose"])
    assert seen["/odom/pose"]["decoded"]["pose"] == pose["pose"]
    path = seen["/odom/path"]["decoded"]
    assert path["header"]["frame_id"] == "odom"
    assert path["poses"] == cdr.decode("nav_msgs/msg/Path", first["/odom/path"])["poses"]
    assert path["poses"]  # the run so far: at least where it started


def test_the_3d_panel_draws_every_topic_the_layout_gives_it(app_modules: Path) -> None:
    """The schemas the app's 3D panel subscribes to (its scene extensions, from its web
    build) include the type of every topic the layout shows there; nav_msgs/Odometry is
    not among them, which is why the pose goes out on /odom/pose as well."""
    drawn = set(run_app(app_modules, "threeDee")["drawn"])
    assert "geometry_msgs/msg/PoseStamped" in drawn  # the reading works
    assert m.TOPICS["/odom"][0] not in drawn
    panels = [c for key, c in CONFIGS.items() if key.startswith("3D!")]
    assert panels
    for config in panels:
        shown = {t for t, s in config["topics"].items() if s.get("visible")}
        assert {"/odom/pose", "/odom/path"} <= shown
        not_drawn = {t: m.TOPICS[t][0] for t in shown if m.TOPICS[t][0] not in drawn}
        assert not_drawn == {}


# ---------------------------------------------------------------- the layout, without Node


def test_the_3d_view_follows_the_base_on_a_grid() -> None:
    for key, config in CONFIGS.items():
        if not key.startswith("3D!"):
            continue
        assert config["followTf"] == "base_link" and config["fixedFrame"] == "odom"
        assert config["followMode"] in ("follow-position", "follow-pose")
        # The app's default camera stands 20 m off: the base is a few pixels.
        assert config["cameraState"]["distance"] <= 5.0
        grids = [layer for layer in config["layers"].values()
                 if layer["layerId"] == "foxglove.Grid" and layer["visible"]]
        assert grids and grids[0]["frameId"] == "odom"
        assert config["topics"]["/odom/path"]["type"] == "line"


def test_every_series_is_enabled() -> None:
    """The app's Plot skips a series whose ``enabled`` is not true (``if
    (!path.enabled)`` in its Plot panel's datasets): every series says it is."""
    series = [(key, p) for key, c in CONFIGS.items()
              if key.startswith(("Plot!", "StateTransitions!")) for p in c["paths"]]
    assert len(series) > 20
    assert [(key, p["value"]) for key, p in series if p.get("enabled") is not True] == []


# The window the app was tried in (issue 31): its 3D panel measured 357 x 529 px, so the
# panels share about 1180 x 970 px.
WINDOW = (1180.0, 970.0)
TOOLBAR_PX = 30  # a panel's toolbar (title)
DIAGNOSTIC_ROW_PX = 30  # the diagnostics summary's rowHeight
STATE_ROW_PX, STATE_AXIS_PX = 64, 30  # the state transitions panel: per series, x axis
CHAR_PX = 7.5  # the app's body2 text (Inter, 0.875 rem), an average character
PIN_PX = 34  # the pin button before each diagnostic


def panel_sizes() -> dict[str, tuple[float, float]]:
    """Each panel's size at WINDOW, as react-mosaic splits it (splitPercentage: the first
    child's share along the split's direction), through the tabs."""
    sizes: dict[str, tuple[float, float]] = {}

    def place(node: Any, width: float, height: float) -> None:
        if isinstance(node, str):
            sizes[node] = (width, height)
            for tab in CONFIGS[node].get("tabs", []) if node.startswith("Tab!") else []:
                place(tab["layout"], width, height - TOOLBAR_PX)
            return
        share = node["splitPercentage"] / 100.0
        if node["direction"] == "row":
            place(node["first"], width * share, height)
            place(node["second"], width * (1 - share), height)
        else:
            place(node["first"], width, height * share)
            place(node["second"], width, height * (1 - share))

    place(LAYOUT["layout"], *WINDOW)
    return sizes


def test_the_panels_have_room_for_what_they_list() -> None:
    """At the window the app was tried in, the drive-state panels show every series (the
    stop reason is the last one), and the diagnostics summary all five statuses, each on
    one line, name and message, as the base says them when all is well."""
    from omnican import default_config
    from omnican.telemetry import TelemetrySettings
    from tests.telemetry.test_telemetry import sample

    sizes = panel_sizes()
    for key, config in CONFIGS.items():
        width, height = sizes[key]
        if key.startswith("StateTransitions!"):
            rows = len(config["paths"])
            needed = TOOLBAR_PX + max(80, rows * STATE_ROW_PX + STATE_AXIS_PX)
            assert height >= needed, (config["foxglovePanelTitle"], height, needed)
        if key.startswith("DiagnosticSummary!"):
            statuses = m.diagnostics(sample(), TelemetrySettings.from_config(
                default_config()))["status"]
            assert height >= TOOLBAR_PX + len(statuses) * DIAGNOSTIC_ROW_PX, height
            for st in statuses:
                shown = f"{st['hardware_id']}: {st['name']}" if st["hardware_id"] else st["name"]
                text_px = PIN_PX + CHAR_PX * (len(shown) + 1 + len(st["message"]))
                assert text_px <= width, (shown, st["message"], width)


def test_the_layout_ships_in_the_package_and_the_startup_line_names_it() -> None:
    """The layout is package data (an installed omnican has it), and the line printed at
    each Foxglove start gives a path that exists wherever omnican is run from."""
    import omnican
    from omnican.live.view import LAYOUT as SHIPPED

    package = Path(omnican.__file__).resolve().parent
    assert SHIPPED.is_file() and SHIPPED.is_relative_to(package)
    assert json.loads(SHIPPED.read_text()) == LAYOUT
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib  # type: ignore[import-not-found,unused-ignore]
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"]["omnican"]
    relative = SHIPPED.relative_to(package)
    assert any(relative.match(p) for p in patterns), patterns


def test_the_startup_line_names_the_layout_where_it_is(tmp_path: Path) -> None:
    pytest.importorskip("foxglove")
    run = subprocess.run([sys.executable, "-m", "omnican", "drive", "--sim", "--fast",
                          "--vx", "0.1", "--duration", "0.2", "--foxglove", "127.0.0.1:0"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=120,
                         check=False, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert run.returncode == 0, run.stderr
    line = next(x for x in (run.stdout + run.stderr).splitlines()
                if "Foxglove: open a connection" in x)
    printed = Path(line.split("(layout: ", 1)[1].rstrip(")"))
    assert printed.is_absolute() and printed.is_file(), line
