"""omnican plot: one figure of a recording: the x-y trajectory, each wheel's
target vs actual rim speed over time, the motor current and DC link voltage the drives
reported (where they did), and the drives' CiA 402 states over time.

    omnican plot RECORDING -o OUT.png [--config TOML]
    omnican plot --sim -o OUT.png     # drive a square on the simulator, then plot it

RECORDING is a recording of omnican (omnican drive ... --record FILE; .log, .asc,
.blf, .csv, .trc, .mcap); --config must describe the base it was recorded on (default:
the demo base). Under --sim the simulator's ground-truth path is drawn over the
odometry; --fast or --sim-speed N run the demo in simulated time. The output format
follows OUT's extension (png, svg, pdf). Needs matplotlib (the plot extra).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import tempfile
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omnican.cli.common import EXIT_OK, UsageError, finite_float, pose_line, positive_float
from omnican.cli.progress import progress_bar
from omnican.cli.session import (
    add_config_argument,
    add_record_argument,
    add_sim_time_arguments,
    load,
    recording,
    session,
)
from omnican.command import motion
from omnican.core.odometry import Pose2D
from omnican.errors import BaseStoppedError
from omnican.plan.health_fields import HEALTH_FIELDS
from omnican.protocol.cia402 import State
from omnican.record import replay

if TYPE_CHECKING:
    from matplotlib.figure import Figure

# matplotlib is an optional extra (omnican[plot]): without it the command still shows
# its help, and running it says what to install (see omnican.cli); with it, it loads
# only when a plot is drawn.

STATE_COLOURS: dict[State, str] = {
    State.UNKNOWN: "#ffffff",
    State.NOT_READY_TO_SWITCH_ON: "#d9d9d9",
    State.SWITCH_ON_DISABLED: "#a6a6a6",
    State.READY_TO_SWITCH_ON: "#9ecae1",
    State.SWITCHED_ON: "#4292c6",
    State.OPERATION_ENABLED: "#41ab5d",
    State.QUICK_STOP_ACTIVE: "#fd8d3c",
    State.FAULT_REACTION_ACTIVE: "#cb181d",
    State.FAULT: "#67000d",
}

TRUTH_PERIOD_S = 0.02
#: The panels of what the drives report, where the recording has it
#: (omnican.plan.health_fields: the values plotted).
HEALTH_PANELS = tuple(f for f in HEALTH_FIELDS if f.plotted)


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("plot", help="plot a recording: trajectory, wheel speeds, current and "
                       "voltage, drive states",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recording", nargs="?", metavar="RECORDING",
                   help="recording made by omnican: a python-can log (.log, .asc, .blf) "
                        "or .mcap")
    p.add_argument("-o", "--output", required=True, metavar="OUT.png",
                   help="image to write (format by extension: png, svg, pdf)")
    p.add_argument("--title", help="figure title (default: the recording's name)")
    add_config_argument(p)
    p.add_argument("--sim", action="store_true",
                   help="instead of a RECORDING: drive a square on simulated drives (a virtual "
                        "bus in this process), record it and plot it with the ground truth")
    demo = p.add_argument_group("the --sim demo")
    demo.add_argument("--square", type=positive_float, default=0.5, metavar="SIDE",
                      help="side of the square, m (default 0.5)")
    demo.add_argument("--sides", type=int, choices=range(1, 5), default=4, metavar="N",
                      help="drive N sides of the square (1-4, default 4), each with its turn")
    demo.add_argument("--speed", type=positive_float, default=0.3, metavar="M/S",
                      help="speed along the sides (default 0.3)")
    demo.add_argument("--omega", type=positive_float, default=1.0, metavar="RAD/S",
                      help="turn rate at the corners (default 1.0)")
    add_record_argument(demo, "keep the demo's recording in FILE")
    demo.add_argument("--sim-scale-error", type=finite_float, default=0.0, metavar="F",
                      help="the simulated wheels turn 1+F times the configured counts per "
                           "metre (default 0: odometry matches the truth)")
    demo.add_argument("--sim-radius-error", type=finite_float, default=0.0, metavar="F",
                      help="the simulated base radius is 1+F times the configured one")
    add_sim_time_arguments(p)
    p.set_defaults(func=run)


# ---------------------------------------------------------------- the figure


def _spans(track: replay.StageTrack, end: float) -> list[tuple[float, float, State]]:
    """(start, width, state) of each state a stage was in."""
    out = []
    changes = track.changes
    for k, change in enumerate(changes):
        stop = changes[k + 1].t if k + 1 < len(changes) else end
        out.append((change.t, max(stop - change.t, 0.0), change.state))
    return out


def _events_text(rep: replay.Replay, limit: int = 8) -> str:
    """EMCY and reboot events as lines under the trajectory (empty when there are none)."""
    events = [(e.t, f"node {e.node_id} EMCY {e.text}") for e in rep.emcy]
    events += [(t, f"node {node} rebooted") for t, node in rep.reboots]
    events.sort()
    lines = [f"{t:7.2f} s  {text}" for t, text in events[:limit]]
    if len(events) > limit:
        lines.append(f"... and {len(events) - limit} more")
    return "events (dotted lines on the time plots):\n" + "\n".join(lines) if lines else ""


def build_figure(rep: replay.Replay, title: str,
                 truth: Sequence[tuple[float, float]] | None = None) -> Figure:
    """The figure of a decoded recording (``truth``: ground-truth x-y path to overlay).

    Drawn with the Agg backend on a bare Figure (no pyplot, no global state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    n = rep.num_wheels
    health = [f for f in HEALTH_PANELS  # where the drives reported them
              if any(len(ts) for ts, _ in rep.health.get(f.quantity, ()))]
    panels = n + len(health)
    fig = Figure(figsize=(14, 2.0 + 1.7 * (panels + 1)), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    state_rows = max(1, len(rep.stages))
    heights = [1.0] * panels + [max(0.8, 0.35 * state_rows)]
    grid = fig.add_gridspec(panels + 1, 2, width_ratios=[1.0, 1.45], height_ratios=heights)
    cut = f"; recording cut: {rep.cut}" if rep.cut else ""
    fig.suptitle(f"{title}\n{rep.duration:.1f} s, {rep.complete_syncs} of {rep.syncs} SYNCs "
                 f"with every wheel's position, {len(rep.emcy)} EMCY{cut}", fontsize=12)

    # Trajectory.
    ax = fig.add_subplot(grid[:, 0])
    ax.set_title("trajectory (odometry, start frame)")
    poses = rep.poses
    if truth:
        tx = [p[0] for p in truth]
        ty = [p[1] for p in truth]
        # Over the odometry (dashes), so both show where they coincide.
        ax.plot(tx, ty, "--", color="C1", lw=2.0, label="simulator ground truth", zorder=3)
        ax.plot(tx[-1], ty[-1], "s", color="C1", ms=11, mfc="none", mew=1.5, zorder=3,
                label="ground truth end", ls="none")
    if len(poses):
        ax.plot(poses[:, 0], poses[:, 1], "-", color="C0", lw=1.5, label="odometry")
        # On a closed path the start and the end coincide: the end is a small filled
        # square, the start a larger ring drawn over it, so both show.
        ax.plot(poses[-1, 0], poses[-1, 1], "s", color="red", ms=6, label="end", zorder=4,
                ls="none")
        ax.plot(poses[0, 0], poses[0, 1], "o", color="green", ms=13, mfc="none", mew=2.0,
                label="start", zorder=5, ls="none")
        span = max(float(poses[:, 0].max() - poses[:, 0].min()),
                   float(poses[:, 1].max() - poses[:, 1].min()), 0.05)
        arrow = 0.08 * span  # heading arrows at the start and the end
        for k, colour, when in ((0, "green", "start"), (len(poses) - 1, "red", "end")):
            x, y, th = poses[k]
            ax.annotate("", xy=(x + arrow * math.cos(th), y + arrow * math.sin(th)), xytext=(x, y),
                        arrowprops={"arrowstyle": "->", "color": colour, "lw": 1.5})
            # in the legend as drawn: the start's arrow green, the end's red
            ax.plot([], [], marker=r"$\rightarrow$", ms=12, color=colour, ls="none",
                    label=f"heading at the {when}")
    else:
        ax.text(0.5, 0.5, "no complete position samples", transform=ax.transAxes,
                ha="center", va="center")
    ax.set_xlabel("x (m)")
    events = _events_text(rep)
    if events:
        ax.annotate(events, (0.0, 0.0), xycoords="axes fraction", xytext=(0, -40),
                    textcoords="offset points", va="top", ha="left", fontsize=9,
                    family="monospace")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.4)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize=9)

    # Wheel speeds.
    first = None
    for i in range(n):
        wax = fig.add_subplot(grid[i, 1], sharex=first) if first else fig.add_subplot(grid[i, 1])
        first = first or wax
        t_target, v_target = rep.target_t[i], rep.target_speed[i]
        if len(t_target):
            wax.step(t_target, v_target, where="post", color="C0", lw=1.2, label="target")
        if rep.sync_t.size:
            wax.plot(rep.sync_t, rep.actual_speed[:, i], color="C3", lw=1.0, alpha=0.85,
                     label="actual (encoder)")
        wax.set_ylabel(f"{rep.wheel_names[i]}\nrim speed (m/s)", fontsize=9)
        wax.grid(True, alpha=0.4)
        wax.tick_params(labelbottom=False)
        if i == 0:
            wax.set_title("wheel target vs actual rim speed", loc="left")
        if i == 0 and wax.get_legend_handles_labels()[0]:
            wax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), fontsize=8, ncols=2,
                       frameon=False, borderaxespad=0.1)
        for ev in rep.emcy:
            wax.axvline(ev.t, color="red" if ev.code else "grey", ls=":", lw=1.0)
        for t, _node in rep.reboots:
            wax.axvline(t, color="purple", ls=":", lw=1.0)

    # What the drives reported (the values plotted), a line per wheel.
    for k, reported in enumerate(health):
        hax = fig.add_subplot(grid[n + k, 1], sharex=first)
        for i, (times, values) in enumerate(rep.health[reported.quantity]):
            if len(times):
                # Each wheel narrower than the one before and drawn over it: wheels that
                # report the same values (one DC link) show as bands, not one hiding another.
                hax.plot(times, values, lw=overlap_width(i, n), color=f"C{i}",
                         label=f"wheel {i}", drawstyle="steps-post", zorder=2 + i * 0.01)
        hax.set_ylabel(reported.axis_label, fontsize=9)
        hax.set_title(reported.plot_title, loc="left")
        hax.grid(True, alpha=0.4)
        hax.tick_params(labelbottom=False)
        if hax.get_legend_handles_labels()[0]:
            hax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), fontsize=8,
                       ncols=n, frameon=False, borderaxespad=0.1)
        for ev in rep.emcy:
            hax.axvline(ev.t, color="red" if ev.code else "grey", ls=":", lw=1.0)

    # Drive states. The last state lasts to the end of the axis: the drives are disabled
    # by the recording's last frames, and that state must show, not a sliver of no width.
    end = time_axis_end(rep.duration)
    sax = fig.add_subplot(grid[panels, 1], sharex=first)
    seen: dict[State, None] = {}
    for row, track in enumerate(rep.stages):
        for start, width, state in _spans(track, end):
            seen[state] = None
            sax.broken_barh([(start, width)], (row - 0.4, 0.8),
                            facecolors=STATE_COLOURS[state], edgecolor="none")
            if width > 0.12 * end:  # name the state where there is room
                dark = state in (State.SWITCHED_ON, State.FAULT, State.FAULT_REACTION_ACTIVE)
                sax.text(start + width / 2, row, str(state), ha="center", va="center",
                         fontsize=8, color="white" if dark else "black", clip_on=True)
    sax.set_yticks(range(len(rep.stages)), [s.label for s in rep.stages], fontsize=9)
    sax.set_ylim(-0.6, max(len(rep.stages), 1) - 0.4)
    sax.invert_yaxis()
    sax.set_xlabel("time since the first frame (s)")
    sax.set_title("CiA 402 drive state", loc="left")
    for ev in rep.emcy:
        rows = [k for k, st in enumerate(rep.stages) if st.node_id == ev.node_id] or [0]
        sax.plot([ev.t] * len(rows), rows, "v", color="red" if ev.code else "grey", ms=7,
                 mec="white")
    for t, node in rep.reboots:
        rows = [k for k, st in enumerate(rep.stages) if st.node_id == node] or [0]
        sax.plot([t] * len(rows), rows, "X", color="purple", ms=7, mec="white")
    if seen:
        order = [s for s in STATE_COLOURS if s in seen]
        sax.legend([Patch(facecolor=STATE_COLOURS[s]) for s in order], [str(s) for s in order],
                   loc="upper center", bbox_to_anchor=(0.5, -0.45), ncols=min(len(order), 4),
                   fontsize=8, frameon=False)
    sax.set_xlim(0.0, end)
    return fig


def overlap_width(i: int, n: int, narrowest: float = 1.1, step: float = 1.6) -> float:
    """Line width of wheel ``i`` of ``n`` in a panel where their lines may coincide."""
    return narrowest + step * (n - 1 - i)


def time_axis_end(duration: float) -> float:
    """Where the time axes end: a little after the last frame (2 %, at least 0.05 s), so
    the state a recording ends in is drawn."""
    return max(duration, 1e-3) + max(0.02 * duration, 0.05)


def summary(rep: replay.Replay) -> str:
    if len(rep.poses):
        x, y, th = rep.poses[-1]
        pose = "end " + pose_line(Pose2D(float(x), float(y), float(th)))
    else:
        pose = "no complete position samples"
    states = ", ".join(f"node {s.node_id} {s.changes[-1].state if s.changes else State.UNKNOWN}"
                       for s in rep.stages)
    return (f"{rep.duration:.2f} s, {rep.frames} frames, {rep.complete_syncs}/{rep.syncs} "
            f"complete SYNCs, {len(rep.emcy)} EMCY; {pose}; last states: {states}")


# ---------------------------------------------------------------- running


def _check_output(path: str) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    out = Path(path)
    fmt = out.suffix.lstrip(".").lower()
    supported = FigureCanvasAgg.get_supported_filetypes()
    if fmt not in supported:
        raise UsageError(f"-o {path}: unknown image format {fmt!r} "
                         f"(use one of {', '.join(sorted(supported))})")
    if not out.parent.is_dir():
        raise UsageError(f"-o {path}: no such directory {out.parent}")
    return out


@contextlib.contextmanager
def _sample_truth(sim: Any,
                  period_s: float = TRUTH_PERIOD_S) -> Iterator[list[tuple[float, float]]]:
    """Collect the simulator's true (x, y) every ``period_s`` while the block runs."""
    path: list[tuple[float, float]] = []
    clock = sim.clock
    if clock.lockstep:  # simulated time: sample as a task of the clock
        def sample(now: float) -> None:
            p = sim.true_pose
            path.append((p.x, p.y))

        handle = clock.every(period_s, sample)
        try:
            yield path
        finally:
            clock.cancel(handle)
        sample(clock.now())
        return
    stop = threading.Event()

    def work() -> None:
        while True:
            p = sim.true_pose
            path.append((p.x, p.y))
            if stop.wait(period_s):
                break

    thread = threading.Thread(target=work, name="omnican-plot-truth", daemon=True)
    thread.start()
    try:
        yield path
    finally:
        stop.set()
        thread.join()
    p = sim.true_pose
    path.append((p.x, p.y))


def _run_demo(args: argparse.Namespace, record: Path) -> tuple[replay.Replay,
                                                                list[tuple[float, float]]]:
    from omnican.analysis.calibration import truth_options
    from omnican.chassis import Chassis

    cfg = load(args)
    options = truth_options(cfg, args.sim_scale_error, args.sim_radius_error)
    try:
        plan = motion.square(args.square, args.speed, args.omega, args.sides)
    except ValueError as exc:  # a side no motion may be (motion.MAX_TRAVEL, ...)
        raise UsageError(f"motion refused: --square {args.square:g}: {exc}") from None
    too_much = motion.plan_problem(plan) or motion.extent_problem(plan, cfg)
    if too_much is not None:  # before anything moves, as drive --square refuses it
        raise UsageError(f"motion refused: {too_much}")
    with (session(args, **options) as s,
          Chassis.open(s.cfg, record=recording(record), clock=s.clock) as base,
          _sample_truth(s.sim) as truth):
        try:
            c = s.cfg.chassis
            with progress_bar(motion.nominal_duration(plan, c.max_accel,
                                                      c.max_angular_accel)) as bar:
                motion.run(base, plan, bar)
        except BaseStoppedError as exc:
            print(f"omnican: warning: base stopped: {exc}", file=sys.stderr)
    return replay.load(record, s.cfg), truth


def config_mismatch(rep: replay.Replay, cfg: Any) -> str | None:
    """Why ``rep`` cannot be of the base ``cfg`` describes, or None: a configured node
    never heard from while no SYNC had every wheel's position (a ZLAC recording read
    with the demo config decoded a 157,000 V DC link and drew no trajectory)."""
    missing = sorted(set(cfg.nodes()) - rep.nodes_heard)
    if not missing or rep.complete_syncs:
        return None
    nodes = ", ".join(str(n) for n in missing)
    return (f"node{'s' if len(missing) > 1 else ''} {nodes} of the config sent no frame, and "
            f"none of its {rep.syncs} SYNCs has every wheel's position")


def run(args: argparse.Namespace) -> int:
    if args.sim == bool(args.recording):
        raise UsageError("give a RECORDING to plot, or --sim for the demo (not both)")
    for flag in ("sim_scale_error", "sim_radius_error"):
        if getattr(args, flag) and not args.sim:
            raise UsageError(f"--{flag.replace('_', '-')} needs --sim")
    if not (-0.5 < args.sim_scale_error < 0.5 and -0.5 < args.sim_radius_error < 0.5):
        raise UsageError("--sim-scale-error and --sim-radius-error must lie within +-0.5")
    out = _check_output(args.output)
    truth: list[tuple[float, float]] | None = None
    if args.sim:
        if args.record:
            record = Path(args.record)
            rep, truth = _run_demo(args, record)
        else:
            with tempfile.TemporaryDirectory(prefix="omnican-plot-") as tmp:
                rep, truth = _run_demo(args, Path(tmp) / "demo.log")
        name = f"simulated square, {args.square:g} m sides" + (
            f" ({args.sides} of 4)" if args.sides < 4 else "")
    else:
        cfg = load(args)
        rep = replay.load(args.recording, cfg)
        if rep.node_frames == 0:
            nodes = ", ".join(str(n) for n in sorted(cfg.nodes()))
            raise UsageError(f"{args.recording}: no frames of nodes {nodes} (recorded on another "
                             "base? give its --config)")
        mismatch = config_mismatch(rep, cfg)
        if mismatch:
            raise UsageError(f"{args.recording}: the recording does not match the config: "
                             f"{mismatch} (recorded on another base? give its --config)")
        name = Path(args.recording).name
    fig = build_figure(rep, args.title or f"omnican: {name}", truth)
    try:
        fig.savefig(out)
    except OSError as exc:
        raise UsageError(f"cannot write {out}: {exc.strerror or exc}") from None
    print(f"wrote {out}: {summary(rep)}")
    return EXIT_OK
