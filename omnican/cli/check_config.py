"""omnican check-config: validate config files and their EDS files offline.

For each file: every table, as the commands that read it check it ([gamepad] and
[ros2] included); each wheel's velocity and position scales (derived ones too) and the
drive target of a slow jog; the PDO plan of every node and the bus load at the
configured rate and bitrate. A file with a problem gets one line naming it; the exit
status is 2 if any file has one. Objects moved by SDO every cycle (and, where the plan
maps objects the EDS marks not PDO-mappable, the SDO fallback if the drive refuses)
get their own load and the highest rate that fits. Touches no bus.
"""

from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING, Any

from omnican.cli.common import EXIT_OK, EXIT_USAGE, fail, positive_int
from omnican.cli.front_ends import check_tables as check_front_ends
from omnican.config import ChassisConfig, load_config, reference_rows
from omnican.errors import ConfigError
from omnican.plan.health_fields import BY_QUANTITY, HEALTH_FIELDS

if TYPE_CHECKING:
    from omnican.plan.node import NodeLayout


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("check-config", help="validate config files and their EDS files offline",
                       description=__doc__, epilog=key_reference(),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", metavar="TOML", nargs="+",
                   help="the robot config(s) to check, e.g. examples/*.toml")
    p.add_argument("--bitrate", type=positive_int, metavar="BIT/S",
                   help="bitrate for the bus load when the config's [bus] has none")
    p.set_defaults(func=run)


def key_reference() -> str:
    """Every config key with its default and meaning (README has the same table)."""
    rows = reference_rows()
    width = max(len(key) for key, _, _ in rows)
    lines = ["config keys (default, meaning); [bus] is passed to can.Bus as it is:"]
    lines += [f"  {key:<{width}}  {default}: {meaning}" for key, default, meaning in rows]
    return "\n".join(lines)


def layouts_or_problems(cfg: ChassisConfig) -> tuple[list[NodeLayout], list[str]]:
    from omnican.plan.node import NodeLayout

    layouts, problems = [], []
    for node_id, wheels in cfg.nodes().items():
        try:
            layouts.append(NodeLayout(node_id, [(cfg.wheels.index(w), w) for w in wheels],
                                      cfg.chassis, cfg.estop))
        except ConfigError as exc:
            problems.append(f"{cfg.source or 'config'}: {exc}")
    return layouts, problems


JOG_SPEED = 0.05  # m/s: the first motion README's power-on checklist asks for


def run(args: argparse.Namespace) -> int:
    codes = [check_file(path, args.bitrate) for path in args.config]
    return max(codes)


def scale_lines(cfg: ChassisConfig) -> list[str]:
    """Each wheel's scales, and what a slow jog asks of its drive."""
    kin = cfg.kinematics()
    lines = []
    for i, w in enumerate(cfg.wheels):
        derived = " (derived)" if w.wheel_radius is not None else ""
        lines.append(f"  wheel {i} ({w.name}, at {kin.angles_deg[i]:g} deg): velocity_scale "
                     f"{w.velocity_scale:.6g} per m/s, position_scale {w.position_scale:.6g} "
                     f"per m{derived}; {JOG_SPEED:g} m/s = target "
                     f"{round(JOG_SPEED * w.velocity_scale)}")
    return lines


def check_file(path: str, bitrate_arg: int | None) -> int:
    """Check one file and print its result; the exit status it earns."""
    from omnican.plan.node import cycle_bits, heartbeat_bits_per_s
    from omnican.plan.pdo import frame_bits
    try:
        cfg = check_front_ends(load_config(path))
    except ConfigError as exc:
        return fail(str(exc), EXIT_USAGE)
    layouts, problems = layouts_or_problems(cfg)
    if problems:
        for line in problems:
            fail(line, EXIT_USAGE)
        return EXIT_USAGE
    c = cfg.chassis
    kin = cfg.kinematics()
    too_high = bus_load_problem(cfg, layouts, bitrate_arg)
    print(f"{cfg.source}: {'FAILED: ' + too_high if too_high else 'OK'}")
    print(f"  base: {len(cfg.wheels)} wheels at {list(kin.angles_deg)} deg, radius "
          f"{', '.join(f'{r:g}' for r in sorted(set(kin.base_radius)))} m; loop {c.rate_hz:g} Hz, "
          f"watchdog {c.cmd_timeout_s:g} s")
    for line in scale_lines(cfg):
        print(line)
    if cfg.imu is not None:
        from omnican.config.imu import describe

        print(f"  {describe(cfg.imu)}")
    for layout in layouts:
        wheels = ", ".join(f"wheel {a.wheel_index} (axis {a.wheel.axis})" for a in layout.axes)
        print(f"  node {layout.node_id}: {layout.eds.name}, mode {layout.mode.short}, {wheels}")
        if not layout.has_consumer:
            print(f"    {host_loss_line(layout)}")
        for line in layout.plan.describe():
            print(f"    {line}")
        refused = layout.refused_plan
        if refused is not None:
            for transfer in refused.sdo:
                print(f"    if the drive refuses: {transfer.describe()}")
        for line in health_lines(layout):
            print(f"    {line}")
    bits = cycle_bits(layout.plan for layout in layouts)
    hb = heartbeat_bits_per_s(cfg)
    health = sum(layout.health.bits_per_s(c.rate_hz) for layout in layouts)
    bitrate = bitrate_arg or (cfg.bus or {}).get("bitrate")
    per_s = bits * c.rate_hz + hb + health
    print(f"  bus: {bits} worst-case bits per cycle ({len(layouts)} nodes + SYNC "
          f"{frame_bits(0)}), {per_s / 1000:.1f} kbit/s at {c.rate_hz:g} Hz with heartbeats "
          "and health reads")
    rates = [int(bitrate)] if bitrate else [500_000, 1_000_000]
    print(f"  health reads ({c.health_rate_hz:g} Hz): {health / 1000:.2f} kbit/s of that, "
          + ", ".join(f"{health / r:.2%} of {r // 1000} kbit/s" for r in rates))
    if bitrate:
        load = per_s / float(bitrate)
        flag = "  TOO HIGH" if load > 0.8 else ""
        print(f"  bus load at {int(bitrate) // 1000} kbit/s: {load:.0%}{flag}")
        if load > 0.8:
            return fail("bus load above 80 %: lower chassis.rate_hz or raise the bitrate",
                        EXIT_USAGE)
    else:
        for rate in (500_000, 1_000_000):
            print(f"  bus load at {rate // 1000} kbit/s: {per_s / rate:.0%}")
    bitrates = [int(bitrate)] if bitrate else [500_000, 1_000_000]
    sdo_bits = sum(layout.plan.sdo_bits() for layout in layouts)
    if sdo_bits:
        print(f"  SDO every cycle: {sdo_bits} of those bits per cycle; "
              + _fits(bits, hb, c.rate_hz, bitrates))
    if any(layout.refused_plan for layout in layouts):
        worst = cycle_bits(layout.refused_plan or layout.plan for layout in layouts)
        print(f"  if the drives refuse what their EDS marks not PDO-mappable: {worst} worst-case "
              "bits per cycle; " + _fits(worst, hb, c.rate_hz, bitrates))
    return EXIT_OK


def bus_load_problem(cfg: ChassisConfig, layouts: list[NodeLayout],
                     bitrate_arg: int | None) -> str | None:
    """The bus load's verdict ahead of the details, for the file's first line: it said
    "OK" and then, lines later, "bus load 518 % TOO HIGH" (exit 2). None: it fits, or
    no bitrate is known (a bitrate that is no number is reported where it is read)."""
    from omnican.plan.node import cycle_bits, heartbeat_bits_per_s

    bitrate = bitrate_arg or (cfg.bus or {}).get("bitrate")
    try:
        rate = float(bitrate) if bitrate and not isinstance(bitrate, bool) else 0.0
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(rate) and rate > 0):
        return None
    c = cfg.chassis
    per_s = (cycle_bits(layout.plan for layout in layouts) * c.rate_hz
             + heartbeat_bits_per_s(cfg)
             + sum(layout.health.bits_per_s(c.rate_hz) for layout in layouts))
    load = per_s / rate
    if load <= 0.8:
        return None
    return f"bus load {load:.0%} at {rate / 1000:g} kbit/s (above 80 %)"


def host_loss_line(layout: NodeLayout) -> str:
    """What a drive without a heartbeat consumer (1016h) does if the host dies: nothing
    (a warning), or stop on its own CAN watchdog where the config sets one (the drive's
    watchdogs: :mod:`omnican.protocol.vendors`, by what its EDS says it is)."""
    from omnican.protocol.vendors import quirks_of

    watchdogs = quirks_of(layout.dictionary).watchdogs
    for write in layout.sdo_writes:
        unit = watchdogs.get((write.entry.index, write.entry.subindex))
        if unit is None:
            continue
        if write.value > 0:
            return (f"no heartbeat consumer (1016h); its CAN watchdog {write.entry.name} "
                    f"({write.entry.address}) = {write.value} {unit} stops it when the bus "
                    "falls silent (as when the host dies)")
        return (f"warning: no heartbeat consumer (1016h), and its CAN watchdog "
                f"{write.entry.name} ({write.entry.address}) is 0 (off): this drive will not "
                "stop by itself if the host dies")
    return ("warning: no heartbeat consumer (1016h): this drive will not stop by itself if "
            "the host dies")


def health_lines(layout: NodeLayout) -> list[str]:
    """What a node reports of its health and how it is read; its e-stop; its
    ``[[wheel.sdo]]`` writes."""
    # What the drives report (but a register), and the following error.
    shown = {f.quantity for f in HEALTH_FIELDS if not f.register} | {"following_error"}
    lines = []
    for axis in layout.axes:
        reads = [r for r in layout.health.reads
                 if axis.wheel_index in r.wheels and r.quantity in shown]
        if reads:
            what = ", ".join(f"{r.quantity.replace('_', ' ')} {r.entry.address}"
                             f"{_unit(r)}" for r in reads)
            lines.append(f"wheel {axis.wheel_index} reports: {what}")
    lines += layout.health.describe()
    if layout.estop is not None:
        entry = layout.estop_entry
        if entry is None:
            lines.append(f"e-stop: this drive has no {layout.estop.object} (not read here)")
        else:
            pressed = "clear" if layout.estop.active_low else "set"
            how = ("from the statusword" if entry.obj is not None and entry.obj.name ==
                   "STATUSWORD" else "with the health values")
            lines.append(f"e-stop: {entry.name} ({entry.address}) bit {layout.estop.bit} "
                         f"{pressed} = pressed ({how})")
    lines += [f"vendor setting in PRE-OPERATIONAL: {w.describe()}" for w in
              layout.sdo_writes]
    return lines


def _unit(read: Any) -> str:
    if read.quantity == "current" and read.scale is None:
        return " (per mille of 6075h, read at startup)"
    if read.quantity == "following_error":
        return " (where a PDO has room)"
    from omnican.plan.health import CONFIG_SCALED

    if read.scale is None or read.quantity not in CONFIG_SCALED:
        return ""  # not the config's scale: the standard's unit (6077h, per mille)
    return f" x {read.scale:g} {BY_QUANTITY[read.quantity].unit}"


def _fits(bits: int, hb_bits_per_s: float, rate_hz: float, bitrates: list[int]) -> str:
    """Bus load at ``rate_hz`` and the highest rate within 80 %, per bitrate."""
    from omnican.plan.node import max_rate_hz
    return "; ".join(
        f"bus load {(bits * rate_hz + hb_bits_per_s) / b:.0%} at {b // 1000} kbit/s, highest "
        f"rate within 80 %: {math.floor(max_rate_hz(bits, hb_bits_per_s, b, 0.8))} Hz"
        for b in bitrates)
