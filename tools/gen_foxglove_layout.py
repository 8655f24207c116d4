"""Write omnican/foxglove/omnican-layout.json (installed with the package; the repository's
foxglove/ links to it): the Foxglove layout for omnican's live view and
MCAP recordings (both publish the same topics; see omnican.telemetry.TOPICS), with a
"drive" tab for driving from Foxglove (--foxglove-control): a Teleop panel on /cmd_vel,
Stop / Recover buttons, odometry reset, the limits as parameters and, under --sim, the
fault console.

The panels are built with the Foxglove SDK's layout types (``pip install
'omnican[foxglove]'``), so their configs use the app's own field names, and written in
the format the app exports and its *Import from file...* reads (``configById`` and a
``layout`` tree of splits), which Foxglove Studio 1.x and Lichtblick read too. The SDK's
own ``Layout.to_json()`` is another format (a tree of containers, for Foxglove's layout
API) that those apps do not import. ``python tools/gen_foxglove_layout.py`` writes it;
``--check`` exits 1 if the file in the repository differs (tests/live/test_view.py runs the
same check).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

LAYOUT = Path(__file__).resolve().parents[1] / "omnican" / "foxglove" / "omnican-layout.json"
WHEELS = 3
CMD_VEL = "/cmd_vel"  # [foxglove] cmd_vel_topic's default
TELEOP_RATE_HZ = 10.0  # well above 1 / cmd_timeout_s (0.5 s): the base keeps moving
TELEOP_SPEED, TELEOP_TURN = 0.3, 1.0  # m/s, rad/s: teleop's starting speeds

# The SDK's panel types -> the ids the app's exported layouts use for them.
EXPORTED_TYPES = {"ThreeDee": "3D", "DiagnosticsSummary": "DiagnosticSummary",
                  "DiagnosticsDetail": "DiagnosticStatusPanel", "ServiceCall": "CallService",
                  "Log": "RosOut", "DataSourceInfo": "SourceInfo",
                  "VariableSlider": "GlobalVariableSliderPanel", "Map": "map"}


def panels() -> Any:
    """The layout as the SDK's types: a TabContainer of splits of panels."""
    import foxglove.layouts as fl

    def series(value: str, **more: Any) -> Any:
        """A plot series; ``enabled`` and the time written out (older apps and
        Lichtblick draw no series that does not say it is enabled)."""
        return fl.PlotSeries(value=value, enabled=True, timestamp_method="receiveTime",
                             **more)

    def state(value: str, label: str) -> Any:
        return fl.StateTransitionsSeries(value=value, label=label, enabled=True,
                                         timestamp_method="receiveTime")

    def scene() -> Any:
        """The base from above and behind, followed as it moves (the view keeps the odom
        frame's orientation, so the trail reads as a map): odometry's pose and path, the
        simulator's truth, on a grid of 0.5 m squares."""
        arrow = (0.4, 0.05, 0.05)  # m: about the base's size (0.19 m radius)
        return fl.ThreeDeePanel(title="base (odom frame)", config=fl.ThreeDeeConfig(
            follow_tf="base_link", fixed_frame="odom", follow_mode="follow-position",
            # frame names small beside the base (the default covers it at this distance)
            scene=fl.BaseRendererSceneSettings(transforms=fl.BaseRendererTransforms(
                label_size=0.06)),
            camera_state=fl.ThreeDeeCameraState(distance=4.0, perspective=True, phi=45.0,
                                                theta_offset=0.0, target_offset=(0, 0, 0)),
            layers={"grid": fl.BaseRendererGridLayerSettings(
                visible=True, layer_id="foxglove.Grid", label="grid (0.5 m)",
                frame_id="odom", size=20.0, divisions=40, line_width=1.0,
                color="#248eff80", order=1)},
            topics={
                "/odom/pose": fl.BaseRendererPoseTopicSettings(
                    visible=True, type="arrow", arrow_scale=arrow, color="#1f77b4"),
                "/odom/path": fl.BaseRendererPosesTopicSettings(
                    visible=True, type="line", line_width=0.02,
                    gradient=("#1f77b440", "#1f77b4")),
                "/sim/true_pose": fl.BaseRendererPoseTopicSettings(
                    visible=True, type="arrow", arrow_scale=arrow, color="#2ca02c"),
                # the wheels' own odometry beside the fused (/odom/pose) where an IMU is
                "/odom/wheels/pose": fl.BaseRendererPoseTopicSettings(
                    visible=True, type="arrow", arrow_scale=arrow, color="#ff7f0e"),
            }))

    def twist() -> Any:
        return fl.PlotPanel(title="twist: command vs measured", config=fl.PlotConfig(
            paths=[series(f"/twist.{kind}.{axis}")
                   for axis in ("vx", "vy", "wz") for kind in ("command", "measured")],
            show_legend=True))

    def states() -> Any:
        return fl.StateTransitionsPanel(title="drive states", config=fl.StateTransitionsConfig(
            paths=[state(f"/wheels.wheels[{i}].state", f"wheel {i}") for i in range(WHEELS)]
            + [state("/status.state", "base"),
               state("/status.stopped_reason", "stopped because")],
            show_points=True))

    def button(service: str, text: str, color: str, tip: str, payload: str = "{}",
               editing: bool = False) -> Any:
        return fl.ServiceCallPanel(title=service, config=fl.ServiceCallConfig(
            service_name=service, request_payload=payload, button_text=text,
            button_color=color, button_tooltip=tip, editing_mode=editing,
            layout="vertical"))

    path = fl.PlotPanel(title="x-y path: odometry vs simulator truth", config=fl.PlotConfig(
        x_axis_val="custom", x_axis_path=fl.PlotXAxisPath(value="/pose2d.x", enabled=True),
        paths=[series("/pose2d.y", x_value_path="/pose2d.x"),
               series("/sim/pose2d.y", x_value_path="/sim/pose2d.x")],
        show_legend=True))
    speeds = fl.PlotPanel(title="wheel rim speed: target vs actual (m/s)", config=fl.PlotConfig(
        paths=[series(f"/wheels.wheels[{i}].{kind}")
               for i in range(WHEELS) for kind in ("target_speed", "actual_speed")],
        show_legend=True))
    travel = fl.PlotPanel(title="wheel travel (m)", config=fl.PlotConfig(
        paths=[series(f"/wheels.wheels[{i}].travel") for i in range(WHEELS)],
        show_legend=True))
    loop = fl.PlotPanel(title="loop rate (Hz) and bus load", config=fl.PlotConfig(
        paths=[series("/status.loop_hz"), series("/status.bus_load", use_right_y_axis=True)],
        show_legend=True))
    diagnostics = fl.DiagnosticsSummaryPanel(title="drives and faults (EMCY)",
                                             config=fl.DiagnosticsSummaryConfig(
                                                 topic_to_render="/diagnostics",
                                                 sort_by_level=True))
    # What the drives report comes in the /wheels messages made while a reading is fresh
    # and is absent from the others (omnican.telemetry.messages: the schema says so): a
    # series of its path is drawn through the messages that have it (the Plot panel skips
    # a message without the path), one point a reading.
    def per_wheel(title: str, field: str, *more: fl.PlotSeries) -> object:
        return fl.PlotPanel(title=title, config=fl.PlotConfig(
            paths=[series(f"/wheels.wheels[{i}].{field}") for i in range(WHEELS)]
            + list(more), show_legend=True))

    current = per_wheel("motor current (A)", "current_a")
    voltage = per_wheel("DC link (V): each drive, and the battery", "voltage_v",
                        series("/battery_state.voltage"))
    temperature = per_wheel("temperature (°C)", "temperature_c")
    alarms = fl.StateTransitionsPanel(title="e-stop and CAN controller",
                                      config=fl.StateTransitionsConfig(paths=[
                                          state("/status.estop", "e-stop"),
                                          state("/status.can_state", "CAN controller")],
                                          show_points=True))
    can = fl.RawMessagesPanel(title="CAN: node 1 position (decoded with the DBC)",
                              config=fl.RawMessagesConfig(topic_path="/can/TPDO2_node1"))
    teleop = fl.TeleopPanel(title=f"drive ({CMD_VEL}; needs --foxglove-control)",
                            config=fl.TeleopConfig(
                                topic=CMD_VEL, publish_rate=TELEOP_RATE_HZ,
                                up_button=fl.TeleopButton(field="linear-x", value=TELEOP_SPEED),
                                down_button=fl.TeleopButton(field="linear-x",
                                                            value=-TELEOP_SPEED),
                                left_button=fl.TeleopButton(field="angular-z", value=TELEOP_TURN),
                                right_button=fl.TeleopButton(field="angular-z",
                                                             value=-TELEOP_TURN),
                                stop_button=fl.TeleopButton(field="linear-x", value=0.0),
                                auto_send_stop_on_release=True))

    def split(direction: str, *items: tuple[float, object]) -> object:
        return fl.SplitContainer(direction=direction,  # type: ignore[arg-type]
                                 items=[fl.SplitItem(proportion=p, content=c)  # type: ignore[arg-type]
                                        for p, c in items])

    # Proportions: at the window the app was tried in (about 1180 x 970 px of panels) the
    # drive states show all five rows (64 px each) and the diagnostics all five statuses
    # on one line each; tests/interop/test_foxglove_app.py checks.
    live = split("row",
                 (1.0, split("column", (1.3, scene()), (1.0, path))),
                 (1.3, split("column", (0.8, speeds), (0.8, twist()), (1.1, states()))),
                 (1.4, split("column", (0.9, diagnostics), (0.6, loop), (0.6, travel))))
    drives = split("row", (1.0, split("column", (1.0, current), (1.0, voltage))),
                   (1.0, split("column", (1.0, temperature), (0.6, alarms))))
    drive = split("row",
                  (1.3, split("column", (1.4, scene()), (0.8, twist()), (1.5, states()))),
                  (1.0, split("column",
                              (1.3, teleop),
                              (0.45, split("row",
                                           (1.0, button("/omnican/stop", "Stop", "#d62728",
                                                        "controlled stop now (anyone may)")),
                                           (1.0, button("/omnican/recover", "Recover",
                                                        "#2ca02c", "clear a latched stop")))),
                              (1.0, fl.ParametersPanel(title="limits (chassis.*)")),
                              (0.7, button("/omnican/reset_odometry", "Reset odometry",
                                           "#1f77b4", "set the odometry pose (m, m, rad)",
                                           '{"x": 0, "y": 0, "theta": 0}', editing=True)),
                              (0.7, button("/omnican/sim/console", "Send", "#ff7f0e",
                                           "the simulator's fault console (--sim): fault N, "
                                           "reboot N, heartbeat N off|on, freeze N, thaw N, "
                                            "jam N, free N, lift N, land N, battery V, "
                                            "estop on|off",
                                           '{"command": "fault 2"}', editing=True)))))
    # The odometry fused with an IMU's gyro beside the wheels' alone (omnican.core.fusion):
    # the headings side by side, the filter's 1-sigma and the gyro bias it learnt, slips.
    heading = fl.PlotPanel(title="heading (deg): fused vs wheels alone", config=fl.PlotConfig(
        paths=[series("/fusion.heading_deg"), series("/fusion.wheels_heading_deg")],
        show_legend=True))
    filter_state = fl.PlotPanel(title="fusion: heading 1-sigma (deg), gyro bias (deg/s)",
                                config=fl.PlotConfig(
                                    paths=[series("/fusion.heading_sigma_deg"),
                                           series("/fusion.gyro_bias_deg_s",
                                                  use_right_y_axis=True)],
                                    show_legend=True))
    slips = fl.StateTransitionsPanel(title="IMU and slip", config=fl.StateTransitionsConfig(
        paths=[state("/fusion.imu", "IMU live"), state("/fusion.slipping", "wheels slip")],
        show_points=True))
    odometry = split("row", (1.2, scene()),
                     (1.0, split("column", (1.0, heading), (0.8, filter_state), (0.5, slips))))
    bus = split("row", (1.0, can),
                (1.0, fl.RawMessagesPanel(title="CAN: frames received (can_msgs/Frame)",
                                          config=fl.RawMessagesConfig(
                                              topic_path="/from_can_bus"))))
    return fl.TabContainer(selected_tab_index=0, tabs=[
        fl.TabItem(title="omnican", content=live),  # type: ignore[arg-type]
        fl.TabItem(title="drive", content=drive),  # type: ignore[arg-type]
        fl.TabItem(title="drives", content=drives),  # type: ignore[arg-type]
        fl.TabItem(title="odometry", content=odometry),  # type: ignore[arg-type]
        fl.TabItem(title="CAN", content=bus),  # type: ignore[arg-type]
    ])


class _Exporter:
    """The SDK's container tree -> the app's exported layout (configById + mosaic)."""

    def __init__(self) -> None:
        self.config_by_id: dict[str, Any] = {}

    def _id(self, kind: str) -> str:
        return f"{kind}!omnican{len(self.config_by_id) + 1}"

    def node(self, item: dict[str, Any]) -> Any:
        kind = item["type"]
        if kind == "panel":
            panel_id = self._id(EXPORTED_TYPES.get(item["panelType"], item["panelType"]))
            config = dict(item.get("config") or {})
            if item.get("title"):
                config["foxglovePanelTitle"] = item["title"]
            self.config_by_id[panel_id] = config
            return panel_id
        if kind == "split":
            return self.split(item["direction"], [(i["proportion"], i["content"])
                                                  for i in item["items"]])
        if kind == "tabs":
            tab_id = self._id("Tab")
            self.config_by_id[tab_id] = {}  # keep the tab panel before its children
            self.config_by_id[tab_id] = {
                "activeTabIdx": item.get("selectedTabIndex", 0),
                "tabs": [{"title": t["title"], "layout": self.node(t["content"])}
                         for t in item["tabs"]]}
            return tab_id
        raise ValueError(f"no exported form for a {kind!r} container")

    def split(self, direction: str, items: list[tuple[float, dict[str, Any]]]) -> Any:
        """An n-way split as the nested two-way splits the app's mosaic has."""
        if len(items) == 1:
            return self.node(items[0][1])
        (first_share, first), rest = items[0], items[1:]
        total = first_share + sum(share for share, _ in rest)
        return {"first": self.node(first), "second": self.split(direction, rest),
                "direction": direction,
                "splitPercentage": round(100.0 * first_share / total, 3)}


def build() -> str:
    tree = json.loads(json.dumps(panels(), default=_plain))
    exporter = _Exporter()
    root = exporter.node(tree)
    layout = {"configById": exporter.config_by_id, "globalVariables": {}, "userNodes": {},
              "playbackConfig": {"speed": 1}, "layout": root}
    return json.dumps(layout, indent=2) + "\n"


def _plain(obj: Any) -> Any:
    """The SDK's own JSON form of one of its layout objects (its to_json's encoder)."""
    import foxglove.layouts as fl

    return fl.Layout._to_json_default(obj)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--check", action="store_true", help="compare instead of writing")
    args = parser.parse_args()
    text = build()
    if args.check:
        if LAYOUT.read_text() != text:
            print(f"{LAYOUT} is out of date: run python tools/gen_foxglove_layout.py",
                  file=sys.stderr)
            return 1
        return 0
    LAYOUT.write_text(text)
    print(f"wrote {LAYOUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
