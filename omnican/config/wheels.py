"""The ``[[wheel]]`` tables (their ``[[wheel.sdo]]`` SDO writes too) and the EDS
files they name: each wheel checked against :data:`~omnican.config.schema.SCHEMA` into a
:class:`~omnican.config.model.WheelConfig`, the wheels checked together, and each EDS
checked for what a node needs.

No I/O beyond parsing the EDS files.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from omnican.config.model import (
    ChassisConfig,
    ChassisSettings,
    SdoWrite,
    WheelConfig,
    derive_scales,
)
from omnican.config.reader import Reader
from omnican.config.schema import SDO_TYPES, WHEEL_EDS
from omnican.core.kinematics import LAYOUTS
from omnican.errors import ConfigError
from omnican.protocol.cia402 import Mode


def parse_wheel(r: Reader, i: int, data: Any, settings: ChassisSettings,
                base_dir: Path | None) -> WheelConfig:
    """``[[wheel]]`` table ``i``: its scales given or derived, its EDS path relative to
    ``base_dir`` (the config file's folder) made whole, its mode the chassis's unless
    given."""
    where = f"wheel[{i}]"
    w = r.table("wheel", data, where)
    node_id, axis = w["node_id"], w["axis"]
    if not 1 <= node_id <= 127:
        raise r.fail(f"{where}.node_id", f"must be 1-127, got {node_id}")
    if not 0 <= axis < 8:
        raise r.fail(f"{where}.axis", f"must be 0-7, got {axis}")
    scales_given = [k for k in ("velocity_scale", "position_scale") if w[k] is not None]
    physical = [k for k in ("gear_ratio", "encoder_cpr", "wheel_radius") if w[k] is not None]
    if scales_given and physical:
        both = ", ".join(scales_given + physical)
        raise r.fail(where, "give either velocity_scale and position_scale or gear_ratio, "
                     f"encoder_cpr and wheel_radius, not both ({both})")
    if physical:
        missing = {"gear_ratio", "encoder_cpr", "wheel_radius"} - set(physical)
        if missing:
            raise r.fail(f"{where}.{sorted(missing)[0]}", "missing (needed to derive the scales)")
        for k in physical:
            r.positive(f"{where}.{k}", w[k])
        try:
            vs, ps = derive_scales(w["gear_ratio"], w["encoder_cpr"], w["wheel_radius"],
                                   w["velocity_unit"], w["invert"])
        except ConfigError as exc:
            raise r.fail(f"{where}.velocity_unit", str(exc).split(": ", 1)[1]) from None
    else:
        for k in ("velocity_scale", "position_scale"):
            if w[k] is None:
                raise r.fail(f"{where}.{k}", "missing (or give gear_ratio, encoder_cpr and "
                             "wheel_radius)")
            if not math.isfinite(w[k]) or w[k] == 0:
                raise r.fail(f"{where}.{k}", f"must be a non-zero finite number, got {w[k]!r}")
        vs, ps = float(w["velocity_scale"]), float(w["position_scale"])
        if w["invert"]:
            vs, ps = -vs, -ps
    if w["base_radius"] is not None:
        r.positive(f"{where}.base_radius", w["base_radius"])
    for k in ("current_scale", "voltage_scale", "temperature_scale"):
        if w[k] is not None and (not math.isfinite(w[k]) or w[k] == 0):
            raise r.fail(f"{where}.{k}", f"must be a non-zero finite number, got {w[k]!r}")
    eds = WHEEL_EDS
    if w["eds"] is not None:
        p = Path(w["eds"]).expanduser()
        eds = p if p.is_absolute() or base_dir is None else (base_dir / p)
    return WheelConfig(
        node_id=node_id,
        axis=axis,
        eds=eds,
        velocity_scale=vs,
        position_scale=ps,
        angle_deg=None if w["angle_deg"] is None else float(w["angle_deg"]),
        drive_angle_deg=None if w["drive_angle_deg"] is None else float(w["drive_angle_deg"]),
        base_radius=None if w["base_radius"] is None else float(w["base_radius"]),
        mode=r.mode(f"{where}.mode", w["mode"]) or settings.mode,
        wheel_radius=float(w["wheel_radius"]) if physical else None,
        current=w["current"],
        current_scale=None if w["current_scale"] is None else float(w["current_scale"]),
        torque=w["torque"],
        voltage=w["voltage"],
        voltage_scale=float(w["voltage_scale"]),
        temperature=w["temperature"],
        temperature_scale=float(w["temperature_scale"]),
        sdo_writes=_parse_sdo_writes(r, where, w["sdo"]),
        serial=w["serial"],
    )


def check_wheels(r: Reader, s: ChassisSettings, wheels: tuple[WheelConfig, ...]) -> None:
    """The wheels together: enough of them, no axis twice, none on the host's node id, the
    layout's number of wheels or an angle on every one."""
    if len(wheels) < 3:
        raise r.fail("wheel", f"an omni base needs at least 3 wheels, got {len(wheels)}")
    seen: dict[tuple[int, int], int] = {}
    serials: dict[int, tuple[int, int]] = {}  # serial -> (node id, wheel)
    for i, w in enumerate(wheels):
        if w.serial is not None:
            node, first = serials.setdefault(w.serial, (w.node_id, i))
            if node != w.node_id:
                raise r.fail(f"wheel[{i}].serial", f"{w.serial} is already wheel[{first}]'s "
                             f"(node {node}): one drive cannot be two nodes")
        key = (w.node_id, w.axis)
        if key in seen:
            raise r.fail(f"wheel[{i}]",
                         f"node {w.node_id} axis {w.axis} is already wheel[{seen[key]}]")
        seen[key] = i
        if w.node_id == s.host_node_id:
            raise r.fail(f"wheel[{i}].node_id", f"{w.node_id} is the host's node id "
                         "(chassis.host_node_id)")
    with_angles = [w.angle_deg is not None for w in wheels]
    if s.layout is not None:
        if any(with_angles):
            raise r.fail("chassis.layout", "give either a layout or angle_deg on every wheel, "
                         "not both")
        n = len(LAYOUTS[s.layout])
        if len(wheels) != n:
            raise r.fail("wheel", f"layout {s.layout!r} has {n} wheels, config has {len(wheels)}")
    elif not all(with_angles):
        i = with_angles.index(False)
        raise r.fail(f"wheel[{i}].angle_deg", "missing: without chassis.layout every wheel "
                     "needs angle_deg")


def check_eds_files(cfg: ChassisConfig, origin: str = "config") -> None:
    """Each wheel's EDS exists, parses, has what every node needs (see
    :mod:`omnican.protocol.eds_check`), the axis, and the objects omnican needs as integers."""
    from omnican.protocol.eds_check import variable_problem
    from omnican.protocol.object_map import (
        AxisObjects,
        Obj,
        declared_types,
        load_dictionary,
        obj_name,
        variable_at,
    )

    cache: dict[Path, Any] = {}
    for i, w in enumerate(cfg.wheels):
        where = f"{origin}: wheel[{i}].eds"
        if w.eds not in cache:
            try:
                cache[w.eds] = load_dictionary(w.eds)
            except ConfigError as exc:
                raise ConfigError(f"{where}: {exc}") from None
        objs = AxisObjects(cache[w.eds], w.axis)
        if w.axis >= max(objs.num_axes, 1):
            raise ConfigError(f"{where}: {w.eds.name} has {objs.num_axes} axis(es), "
                              f"no axis {w.axis}")
        mode = w.mode or Mode.PROFILE_VELOCITY
        target = Obj.VL_TARGET if mode is Mode.VELOCITY else Obj.TARGET_VELOCITY
        for obj in (Obj.CONTROLWORD, Obj.STATUSWORD, Obj.POSITION_ACTUAL, Obj.MODE, target):
            entry = objs.get(obj)
            if entry is None:
                raise ConfigError(
                    f"{where}: {w.eds.name} lacks {obj_name(obj)} "
                    f"(0x{int(obj):04X}) for axis {w.axis}, needed in {mode.short} mode"
                )
            var = variable_at(cache[w.eds], entry.index, entry.subindex)
            problem = (variable_problem(var, entry.name, declared_types(w.eds))
                       if var is not None else None)
            if problem:
                raise ConfigError(f"{where}: EDS {w.eds}: {problem}")



def _parse_sdo_writes(r: Reader, where: str, raw: Any) -> tuple[SdoWrite, ...]:
    """A wheel's [[wheel.sdo]] tables (checked against the EDS later)."""
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise r.fail(f"{where}.sdo", "must be an array of tables ([[wheel.sdo]])")
    out = []
    for k, item in enumerate(raw):
        t = r.table("wheel.sdo", item, f"{where}.sdo[{k}]")
        kind = t["type"]
        if kind is not None and kind not in SDO_TYPES:
            raise r.fail(f"{where}.sdo[{k}].type", f"unknown type {kind!r} (one of "
                         f"{', '.join(SDO_TYPES)})")
        value = t["value"]
        if isinstance(value, float) and not math.isfinite(value):
            raise r.fail(f"{where}.sdo[{k}].value", f"must be finite, got {value!r}")
        out.append(SdoWrite(t["object"], value, kind))
    return tuple(out)

