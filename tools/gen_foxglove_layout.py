"""Write foxglove/omnican-layout.json: the Foxglove layout for omnican's live view and
MCAP recordings (both publish the same topics; see omnican.telemetry.TOPICS).

Built with the Foxglove SDK's layout types (``pip install 'omnican[foxglove]'``).
``python tools/gen_foxglove_layout.py`` writes it; ``--check`` exits 1 if the file in the
repository differs (tests/test_live.py runs the same check).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

LAYOUT = Path(__file__).resolve().parents[1] / "foxglove" / "omnican-layout.json"
WHEELS = 3
COLORS = ("#1f77b4", "#d62728", "#2ca02c")


def build() -> str:
    import foxglove.layouts as fl

    scene = fl.ThreeDeePanel(title="base (odom frame)", config=fl.ThreeDeeConfig(
        follow_tf="base_link", fixed_frame="odom", topics={
            "/odom": fl.BaseRendererPoseTopicSettings(visible=True, type="arrow",
                                                      color="#1f77b4"),
            "/sim/true_pose": fl.BaseRendererPoseTopicSettings(visible=True, type="arrow",
                                                               color="#2ca02c"),
        }))
    path = fl.PlotPanel(title="x-y path: odometry vs simulator truth", config=fl.PlotConfig(
        x_axis_val="custom", x_axis_path=fl.PlotXAxisPath(value="/pose2d.x"),
        paths=[fl.PlotSeries(value="/pose2d.y", x_value_path="/pose2d.x"),
               fl.PlotSeries(value="/sim/pose2d.y", x_value_path="/sim/pose2d.x")],
        show_legend=True))
    twist = fl.PlotPanel(title="twist: command vs measured", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=f"/twist.{kind}.{axis}")
               for axis in ("vx", "vy", "wz") for kind in ("command", "measured")],
        show_legend=True))
    speeds = fl.PlotPanel(title="wheel rim speed: target vs actual (m/s)", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=f"/wheels.wheels[{i}].{kind}")
               for i in range(WHEELS) for kind in ("target_speed", "actual_speed")],
        show_legend=True))
    travel = fl.PlotPanel(title="wheel travel (m)", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=f"/wheels.wheels[{i}].travel") for i in range(WHEELS)],
        show_legend=True))
    states = fl.StateTransitionsPanel(title="drive states", config=fl.StateTransitionsConfig(
        paths=[fl.StateTransitionsSeries(value=f"/wheels.wheels[{i}].state",
                                         label=f"wheel {i}") for i in range(WHEELS)]
        + [fl.StateTransitionsSeries(value="/status.state", label="base"),
           fl.StateTransitionsSeries(value="/status.stopped_reason", label="stopped because")],
        show_points=True))
    loop = fl.PlotPanel(title="loop rate (Hz) and bus load", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value="/status.loop_hz"),
               fl.PlotSeries(value="/status.bus_load", use_right_y_axis=True)],
        show_legend=True))
    diagnostics = fl.DiagnosticsSummaryPanel(title="drives and faults (EMCY)",
                                             config=fl.DiagnosticsSummaryConfig(
                                                 topic_to_render="/diagnostics",
                                                 sort_by_level=True))
    def per_wheel(title: str, field: str, *more: fl.PlotSeries) -> object:
        return fl.PlotPanel(title=title, config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=f"/wheels.wheels[{i}].{field}") for i in range(WHEELS)]
            + list(more), show_legend=True))

    current = per_wheel("motor current (A)", "current_a")
    voltage = per_wheel("DC link (V): each drive, and the battery", "voltage_v",
                        fl.PlotSeries(value="/battery_state.voltage"))
    temperature = per_wheel("temperature (°C)", "temperature_c")
    alarms = fl.StateTransitionsPanel(title="e-stop and CAN controller",
                                      config=fl.StateTransitionsConfig(paths=[
                                          fl.StateTransitionsSeries(value="/status.estop",
                                                                    label="e-stop"),
                                          fl.StateTransitionsSeries(value="/status.can_state",
                                                                    label="CAN controller")],
                                          show_points=True))
    can = fl.RawMessagesPanel(title="CAN: node 1 position (decoded with the DBC)",
                              config=fl.RawMessagesConfig(topic_path="/can/TPDO2_node1"))

    def split(direction: str, *items: tuple[float, object]) -> object:
        return fl.SplitContainer(direction=direction,  # type: ignore[arg-type]
                                 items=[fl.SplitItem(proportion=p, content=c)  # type: ignore[arg-type]
                                        for p, c in items])

    live = split("row",
                 (1.0, split("column", (1.2, scene), (1.0, path))),
                 (1.3, split("column", (1.0, speeds), (1.0, twist), (0.8, states))),
                 (1.0, split("column", (1.0, diagnostics), (0.6, loop), (0.8, travel))))
    drives = split("row", (1.0, split("column", (1.0, current), (1.0, voltage))),
                   (1.0, split("column", (1.0, temperature), (0.6, alarms))))
    bus = split("row", (1.0, can),
                (1.0, fl.RawMessagesPanel(title="CAN: frames received (can_msgs/Frame)",
                                          config=fl.RawMessagesConfig(
                                              topic_path="/from_can_bus"))))
    layout = fl.Layout(content=fl.TabContainer(selected_tab_index=0, tabs=[
        fl.TabItem(title="omnican", content=live),  # type: ignore[arg-type]
        fl.TabItem(title="drives", content=drives),  # type: ignore[arg-type]
        fl.TabItem(title="CAN", content=bus),  # type: ignore[arg-type]
    ]))
    return json.dumps(json.loads(layout.to_json()), indent=2) + "\n"


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
