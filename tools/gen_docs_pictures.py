#!/usr/bin/env python3
"""The documentation's pictures, made from the code (the docs build runs this):

- ``geometry-b21.svg``, ``geometry-a12.svg``: each preset's wheels, where each wheel
  sits and the way it drives for a positive rim speed, in the body frame (REP-103: x
  forward, y left), drawn from :class:`omnican.core.kinematics.OmniKinematics`;
- ``teleop.svg``: the teleop dashboard of the simulated base after a scripted drive, on
  an 80x24 terminal (rich exports the very screen ``omnican teleop`` draws);
- ``plot.png``: ``omnican plot --sim --fast`` (a square on the simulated base);
- ``layers.svg``: the layers (:mod:`omnican.layers`) and the imports between them, read
  from the code as ``tests/test_layers.py`` reads them.

Run: ``python tools/gen_docs_pictures.py OUT_DIR`` (needs matplotlib and rich: the docs
extra and the base install; nothing of the tests). A picture whose inputs did not change
is rewritten the same.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

# Same bytes for the same picture: no date, no random ids.
plt.rcParams["svg.hashsalt"] = "omnican"
SVG_META = {"Date": None, "Creator": "omnican tools/gen_docs_pictures.py"}


def geometry(layout: str, out: Path) -> None:
    from omnican.core.kinematics import LAYOUTS, OmniKinematics

    radius = 0.19
    kin = OmniKinematics.from_layout(layout, base_radius=radius)
    fig, ax = plt.subplots(figsize=(4.2, 4.2))
    ax.add_patch(plt.Circle((0, 0), radius, fill=False, lw=1.5, color="0.4"))
    for i, (a, b) in enumerate(zip(kin.angles_deg, kin.drive_angles_deg, strict=True)):
        x, y = radius * math.cos(math.radians(a)), radius * math.sin(math.radians(a))
        # the wheel: a short bar along its drive direction
        dx, dy = math.cos(math.radians(b)), math.sin(math.radians(b))
        ax.plot([x - 0.04 * dx, x + 0.04 * dx], [y - 0.04 * dy, y + 0.04 * dy], lw=7,
                color="0.2", solid_capstyle="butt")
        ax.annotate("", xy=(x + 0.09 * dx, y + 0.09 * dy), xytext=(x, y),
                    arrowprops={"arrowstyle": "-|>", "color": "tab:red", "lw": 1.5})
        lx, ly = 1.33 * x, 1.33 * y
        ax.text(lx, ly, f"wheel {i}\n{a:g}°", ha="center", va="center", fontsize=8)
    ax.annotate("", xy=(0.1, 0), xytext=(0, 0),
                arrowprops={"arrowstyle": "-|>", "color": "tab:blue", "lw": 1.5})
    ax.annotate("", xy=(0, 0.1), xytext=(0, 0),
                arrowprops={"arrowstyle": "-|>", "color": "tab:green", "lw": 1.5})
    ax.text(0.105, -0.018, "x", color="tab:blue", fontsize=9)
    ax.text(-0.025, 0.1, "y", color="tab:green", fontsize=9)
    ax.set_title(f'layout = "{layout}": wheels at {", ".join(f"{a:g}" for a in LAYOUTS[layout])}'
                 " deg\n(red: positive rim speed)", fontsize=9)
    ax.set_aspect("equal")
    ax.set_xlim(-0.33, 0.33)
    ax.set_ylim(-0.33, 0.33)
    ax.axis("off")
    fig.tight_layout()
    fig.savefig(out, metadata=SVG_META)
    plt.close(fig)


#: The terminal the teleop picture is of: the 80x24 screen teleop is made for.
TELEOP_SCREEN = (80, 24)


def teleop(out: Path) -> None:
    from rich.console import Console

    from omnican import Chassis, Twist
    from omnican.cli.dashboard import dashboard
    from omnican.cli.session import SIM_BITRATE
    from omnican.cli.terminal import RecentEvents
    from omnican.clock import SimClock
    from omnican.command.teleop import TeleopModel
    from omnican.config import default_config
    from omnican.sim import SimulatedBase

    # as under omnican teleop --sim: the simulated bus has the demo base's nominal bitrate
    cfg = default_config(bus={"interface": "virtual", "channel": f"docs-{uuid.uuid4().hex}",
                              "bitrate": SIM_BITRATE})
    clock = SimClock()
    keys = TeleopModel.for_config(cfg, 0.3, 1.0, 0.6)
    command = Twist(0.3, 0.0, 0.5)
    with SimulatedBase.from_config(cfg, clock=clock), \
            Chassis.open(cfg, clock=clock) as base:
        end = clock.now() + 3.0
        while clock.now() < end:
            base.set_velocity(command.vx, command.vy, command.wz)
            clock.sleep(0.05)
        events = RecentEvents()
        events.lines.append("12:00:00 base running: the keys drive it")
        width, height = TELEOP_SCREEN
        screen = dashboard(base, keys, command, "omnican teleop - simulated base, nodes 1, 2, 3",
                           events, "", width=width, height=height)
        console = Console(record=True, width=width, height=height, force_terminal=True,
                          color_system="truecolor",
                          file=open(os.devnull, "w"))  # noqa: SIM115 (closed below)
        console.print(screen)
        console.file.close()
        svg = console.export_svg(title="omnican teleop --sim", unique_id="teleop")
    out.write_text(svg)


def plot(out: Path) -> None:
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    env = {**os.environ, "PYTHONPATH": path}
    subprocess.run([sys.executable, "-m", "omnican", "plot", "--sim", "--fast", "-o", str(out)],
                   check=True, env=env, cwd=ROOT, stdout=subprocess.DEVNULL)


def layers(out: Path) -> None:
    import omnican
    from omnican.layers import LAYERS, SHARED, crossing, imports_in

    rows = [sorted(layer) for layer in LAYERS]
    pos: dict[str, tuple[float, float]] = {}
    for r, row in enumerate(rows):
        for c, name in enumerate(row):
            pos[name] = ((c - (len(row) - 1) / 2) * 2.3, r * 1.0)
    package = ROOT / "omnican"
    edges: set[tuple[str, str]] = set()
    for path in sorted(package.rglob("*.py")):
        name = ".".join(path.relative_to(package).with_suffix("").parts)
        for target in imports_in(path.read_text(), omnican._HOMES, str(path)):
            if crossing(name, target) is not None:
                edges.add((name.split(".")[0], target.split(".")[0]))
    fig, ax = plt.subplots(figsize=(9, 8))
    for a, b in sorted(edges):
        if b in SHARED:  # every layer may use them: drawn once, as the bottom row
            continue
        (x0, y0), (x1, y1) = pos[a], pos[b]
        up = y1 > y0
        span = abs(y0 - y1)
        end = 0.2 if up else -0.2
        ax.annotate("", xy=(x1, y1 - end), xytext=(x0, y0 + end),
                    arrowprops={"arrowstyle": "-|>", "color": "tab:red" if up else "0.6",
                                "lw": 1.2 if up else 0.7, "shrinkA": 3, "shrinkB": 3,
                                "connectionstyle": f"arc3,rad={0.0 if span <= 1 else 0.25}"})
    for name, (x, y) in pos.items():
        label = name if name in SHARED else f"{name}/"
        ax.text(x, y, label, ha="center", va="center", fontsize=10,
                bbox={"boxstyle": "round,pad=0.35", "fc": "#eef3fb" if name not in SHARED
                      else "#f3f3f3", "ec": "#4a6fa5"})
    half = (max(len(row) for row in rows) - 1) / 2 * 2.3 + 1.0
    ax.set_xlim(-half, half)
    ax.set_ylim(-0.7, len(rows) - 0.3)
    ax.axis("off")
    ax.set_title("omnican's layers, lowest first; an arrow is an import, downward\n"
                 "(the bottom row is what every layer may use; red: an import upward)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(out, metadata=SVG_META)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="directory to write the pictures into")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for layout in ("b21", "a12"):
        geometry(layout, args.out / f"geometry-{layout}.svg")
    teleop(args.out / "teleop.svg")
    plot(args.out / "plot.png")
    layers(args.out / "layers.svg")
    return 0


if __name__ == "__main__":
    sys.exit(main())
