"""How a config's wheels become simulated drives: one drive per node, its axes' units,
and what it reports as the config reads it (the health signals, the e-stop input)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import canopen

from omnican.config import ChassisConfig, WheelConfig
from omnican.errors import ConfigError
from omnican.protocol.object_map import Obj, eds_axes
from omnican.sim.drive import SimulatedDrive
from omnican.sim.health import QUANTITIES, EstopInput
from omnican.sim.scheduler import SimScheduler


def make_drive(network: canopen.Network, node_id: int, wheels: list[WheelConfig],
               scheduler: SimScheduler, options: Mapping[str, Any]) -> SimulatedDrive:
    """The simulated drive of node ``node_id`` on ``network``, its axes the ``wheels``
    of the config on that node (each axis's counts per drive velocity unit from the
    wheel's scales); ``options``: :class:`SimulatedDrive` arguments."""
    eds = {w.eds for w in wheels}
    if len(eds) > 1:
        raise ConfigError(f"node {node_id}: its wheels name different EDS files "
                          f"({', '.join(sorted(str(e) for e in eds))})")
    # The drive's axes, as the drive counts them (Device.num_axes), before it is made.
    n_axes = max(1, eds_axes(wheels[0].eds))
    cpu = [1.0] * n_axes
    for w in wheels:
        cpu[w.axis] = w.position_scale / w.velocity_scale
    return SimulatedDrive(network, node_id, wheels[0].eds, scheduler=scheduler,
                          counts_per_unit=cpu, **options)


def health_wiring(cfg: ChassisConfig, true_scale: Sequence[float]) -> dict[int, dict[str, Any]]:
    """Per node, what the drives need to report as ``cfg`` reads them: each axis's counts
    per metre (the motor current follows the wheel's motion), the vendor objects the
    config names and their units, and where the e-stop is wired."""
    from omnican.plan.node import node_layouts

    out: dict[int, dict[str, Any]] = {}
    for layout in node_layouts(cfg):
        axes = {a.wheel_index: a.wheel.axis for a in layout.axes}
        n_axes = max(1, layout.axes[0].objs.num_axes)
        per_m = [0.0] * n_axes
        for a in layout.axes:
            per_m[a.wheel.axis] = a.wheel.position_scale * true_scale[a.wheel_index]
        # A config's scale says the object's unit: the simulator serves it so (6078h and
        # 6077h count per mille whatever: their scale is the rated current's).
        signals = {r.key: (r.quantity, axes[r.wheels[0]], r.scale)
                   for r in layout.health.reads
                   if r.quantity in QUANTITIES and r.scale is not None and
                   not (r.quantity == "torque" and r.entry.obj is Obj.TORQUE_ACTUAL)}
        options: dict[str, Any] = {"counts_per_m": per_m, "signals": signals}
        entry, estop = layout.estop_entry, layout.estop
        if estop is not None and entry is not None:
            options["estop_input"] = EstopInput(entry.index, entry.subindex, estop.bit,
                                                estop.active_low)
        out[layout.node_id] = options
    return out
