"""omnican check-config: validate a config and its EDS files offline.

Prints the PDO plan of every node and the bus load at the configured rate and
bitrate, or one line per problem (exit 2). Objects moved by SDO every cycle (and,
where the plan maps objects the EDS marks not PDO-mappable, the SDO fallback if the
drive refuses) get their own load and the highest rate that fits. Touches no bus.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from omnican.cli.common import EXIT_OK, EXIT_USAGE, fail, positive_int
from omnican.config import ChassisConfig, load_config, reference_rows
from omnican.errors import ConfigError
from omnican.layout import NodeLayout, cycle_bits, heartbeat_bits_per_s, max_rate_hz
from omnican.pdoplan import frame_bits


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("check-config", help="validate a config and its EDS files offline",
                       description=__doc__, epilog=key_reference(),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", metavar="TOML", help="the robot config to check")
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
    layouts, problems = [], []
    for node_id, wheels in cfg.nodes().items():
        try:
            layouts.append(NodeLayout(node_id, [(cfg.wheels.index(w), w) for w in wheels],
                                      cfg.chassis))
        except ConfigError as exc:
            problems.append(f"{cfg.source or 'config'}: {exc}")
    return layouts, problems


def run(args: argparse.Namespace) -> int:
    try:
        cfg = load_config(args.config)
    except ConfigError as exc:
        return fail(str(exc), EXIT_USAGE)
    layouts, problems = layouts_or_problems(cfg)
    if problems:
        for line in problems:
            fail(line, EXIT_USAGE)
        return EXIT_USAGE
    c = cfg.chassis
    kin = cfg.kinematics()
    print(f"{cfg.source}: OK")
    print(f"  base: {len(cfg.wheels)} wheels at {list(kin.angles_deg)} deg, radius "
          f"{', '.join(f'{r:g}' for r in sorted(set(kin.base_radius)))} m; loop {c.rate_hz:g} Hz, "
          f"watchdog {c.cmd_timeout_s:g} s")
    for layout in layouts:
        wheels = ", ".join(f"wheel {a.wheel_index} (axis {a.wheel.axis})" for a in layout.axes)
        print(f"  node {layout.node_id}: {layout.eds.name}, mode {layout.mode.short}, {wheels}")
        if not layout.has_consumer:
            print("    warning: no heartbeat consumer (1016h): this drive will not stop by "
                  "itself if the host dies")
        for line in layout.plan.describe():
            print(f"    {line}")
        refused = layout.refused_plan
        if refused is not None:
            for transfer in refused.sdo:
                print(f"    if the drive refuses: {transfer.describe()}")
    bits = cycle_bits(layout.plan for layout in layouts)
    hb = heartbeat_bits_per_s(cfg)
    bitrate = args.bitrate or (cfg.bus or {}).get("bitrate")
    per_s = bits * c.rate_hz + hb
    print(f"  bus: {bits} worst-case bits per cycle ({len(layouts)} nodes + SYNC "
          f"{frame_bits(0)}), {per_s / 1000:.1f} kbit/s at {c.rate_hz:g} Hz with heartbeats")
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


def _fits(bits: int, hb_bits_per_s: float, rate_hz: float, bitrates: list[int]) -> str:
    """Bus load at ``rate_hz`` and the highest rate within 80 %, per bitrate."""
    return "; ".join(
        f"bus load {(bits * rate_hz + hb_bits_per_s) / b:.0%} at {b // 1000} kbit/s, highest "
        f"rate within 80 %: {math.floor(max_rate_hz(bits, hb_bits_per_s, b, 0.8))} Hz"
        for b in bitrates)
