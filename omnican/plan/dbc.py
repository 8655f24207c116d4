"""DBC databases of a base's CAN frames, derived from its config and EDS files.

Every PDO of each node's plan (``omnican.plan.node``), its health TPDOs included, becomes a
message with one
little-endian signal per mapped object, placed, sized and signed as the control loop's
codec (:class:`omnican.plan.codec.PdoCodec`) packs it, plus NMT, SYNC, EMCY and heartbeats. The
bundled ``dbc/omnican.dbc`` is this for the demo base (``tools/gen_dbc.py`` writes it,
``tests/plan/test_dbc.py`` keeps it in step); ``omnican monitor --config`` builds one for
any robot so vendor drives decode under their own names.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import cantools
from cantools.database.can import Message, Node, Signal
from cantools.database.conversion import BaseConversion
from cantools.database.namedsignalvalue import NamedSignalValue

from omnican.config import ChassisConfig, default_config
from omnican.plan.codec import PdoCodec, value_range
from omnican.plan.health import CONFIG_SCALED
from omnican.plan.health_fields import BY_QUANTITY
from omnican.plan.node import NodeLayout, node_layouts
from omnican.plan.pdo import PlannedPdo
from omnican.protocol.cia301 import (
    COB_ID_MASK,
    EMCY_BASE,
    EMCY_COB_ID_OBJECT,
    HEARTBEAT_BASE,
    NMT_COB_ID,
    NMT_COMMAND_NAMES,
    NMT_STATE_NAMES,
    SYNC_COB_ID,
)
from omnican.protocol.cia402 import EMCY_CODES, MODE_NAMES
from omnican.protocol.object_map import Entry, Obj

HOST = "Host"

#: DBC signal names of the objects omnican maps.
SIGNAL_NAMES: dict[Obj, str] = {
    Obj.CONTROLWORD: "Controlword",
    Obj.STATUSWORD: "Statusword",
    Obj.MODE: "ModeOfOperation",
    Obj.MODE_DISPLAY: "ModeDisplay",
    Obj.ERROR_CODE: "ErrorCode",
    Obj.TARGET_VELOCITY: "TargetVelocity",
    Obj.VELOCITY_ACTUAL: "VelocityActual",
    Obj.POSITION_ACTUAL: "PositionActual",
    Obj.VL_TARGET: "VlTargetVelocity",
    Obj.VL_DEMAND: "VlVelocityDemand",
    Obj.VL_ACTUAL: "VlVelocityActual",
    Obj.CURRENT_ACTUAL: "CurrentActual",
    Obj.TORQUE_ACTUAL: "TorqueActual",
    Obj.DC_LINK_VOLTAGE: "DcLinkVoltage",
    Obj.FOLLOWING_ERROR: "FollowingError",
    Obj.DIGITAL_INPUTS: "DigitalInputs",
}

#: Units of the bundled EDS (its comment: increments, increments/s; vl in rpm).
UNITS: dict[Obj, str] = {
    Obj.TARGET_VELOCITY: "inc/s",
    Obj.VELOCITY_ACTUAL: "inc/s",
    Obj.POSITION_ACTUAL: "inc",
    Obj.VL_TARGET: "rpm",
    Obj.VL_DEMAND: "rpm",
    Obj.VL_ACTUAL: "rpm",
    Obj.CURRENT_ACTUAL: "permille",  # of the rated current (6075h)
    Obj.TORQUE_ACTUAL: "permille",  # of the rated torque
    Obj.DC_LINK_VOLTAGE: "mV",
    Obj.FOLLOWING_ERROR: "inc",
}

#: Value tables of the objects that hold enumerations.
CHOICES: dict[Obj, dict[int, str]] = {
    Obj.MODE: MODE_NAMES,
    Obj.MODE_DISPLAY: MODE_NAMES,
    Obj.ERROR_CODE: {**EMCY_CODES, 0: "no error"},  # 603Fh: the last error, 0 = none
}

NMT_STATES = {state: name.lower() for state, name in NMT_STATE_NAMES.items()}


def node_name(node_id: int) -> str:
    return f"Node{node_id}"


def signal_name(entry: Entry) -> str:
    """``TargetVelocity`` for 60FFh; CamelCase of the EDS name for other objects."""
    if entry.obj is not None and entry.obj in SIGNAL_NAMES:
        return SIGNAL_NAMES[entry.obj]
    words = "".join(c if c.isalnum() else " " for c in entry.name).split()
    return "".join(w[:1].upper() + w[1:] for w in words) or f"Object{entry.index:04X}"


def _conversion(choices: dict[int, str] | None, scale: float = 1) -> BaseConversion:
    table: OrderedDict[int, str | NamedSignalValue] | None = (
        OrderedDict(sorted(choices.items())) if choices else None)
    return BaseConversion.factory(scale=scale, offset=0, choices=table)


def _signal(name: str, start: int, bits: int, signed: bool, receivers: list[str],
            unit: str | None = None, comment: str | None = None,
            choices: dict[int, str] | None = None, scale: float = 1) -> Signal:
    lo, hi = value_range(bits, signed)
    return Signal(name=name, start=start, length=bits, byte_order="little_endian",
                  is_signed=signed, conversion=_conversion(choices, scale),
                  minimum=round(lo * scale, 9), maximum=round(hi * scale, 9), unit=unit,
                  comment=comment, receivers=receivers)


#: Units of what the drives report, in the config's scales (health reads).
HEALTH_UNITS = {q: BY_QUANTITY[q].unit for q in CONFIG_SCALED}


def _health_scale(layout: NodeLayout, entry: Entry) -> tuple[float, str] | None:
    """The config's scale and unit of a vendor object read as health (e.g. a motor
    temperature 0x2100 in 0.1 degC: without it the DBC showed MotorTemperature=250)."""
    health = getattr(layout, "health", None)
    for read in health.reads if health is not None else ():
        e = read.entry
        if ((e.index, e.subindex) == (entry.index, entry.subindex) and read.scale is not None
                and read.quantity in HEALTH_UNITS):
            return float(read.scale), HEALTH_UNITS[read.quantity]
    return None


def pdo_message(layout: NodeLayout, pdo: PlannedPdo, tx: bool, rate_hz: float) -> Message:
    """One PDO of ``layout``'s plan as a DBC message (little-endian signals, in order)."""
    kind = "TPDO" if tx else "RPDO"
    node = node_name(layout.node_id)
    sender, receiver = (node, HOST) if tx else (HOST, node)
    codec = PdoCodec(pdo)
    signals: list[Signal] = []
    for f in codec.fields:
        entry = f.entry
        name = signal_name(entry)
        if any(s.name == name for s in signals):  # e.g. two axes of one drive
            name = f"{name}_{entry.index:04X}sub{entry.subindex}"
        obj = entry.obj
        unit = UNITS.get(obj) if obj is not None else None
        scale: float = 1
        if unit is None and tx:  # a vendor object: the config may say what it counts in
            scaled = _health_scale(layout, entry)
            if scaled is not None:
                scale, unit = scaled
        signals.append(_signal(
            name, f.start_bit, f.bits, f.signed, [receiver], unit=unit,
            comment=f"{entry.name} ({entry.address})",
            choices=CHOICES.get(obj) if obj is not None else None, scale=scale))
    return Message(
        frame_id=codec.cob_id,
        name=f"{kind}{pdo.number}_node{layout.node_id}",
        length=codec.length,
        signals=signals,
        comment=f"node {layout.node_id}: {pdo.describe(kind)}",
        senders=[sender],
        cycle_time=round(1000.0 * max(1, pdo.trans_type) / rate_hz) if pdo.cyclic else None,
    )


def _emcy_cob_id(layout: NodeLayout) -> int:
    """COB-ID EMCY (1014h) of the node from its EDS, else the default 0x80 + id."""
    item: Any = layout.dictionary.get(EMCY_COB_ID_OBJECT)
    default = getattr(item, "default", None)
    if isinstance(default, int) and default & COB_ID_MASK:
        return default & COB_ID_MASK
    return EMCY_BASE + layout.node_id


def build_database(cfg: ChassisConfig | None = None) -> Any:
    """The cantools database of ``cfg``'s frames (default: the demo base)."""
    cfg = cfg or default_config()
    layouts = node_layouts(cfg)
    rate_hz = cfg.chassis.rate_hz
    heartbeat_ms = cfg.chassis.heartbeat_ms
    nodes = [HOST] + [node_name(n.node_id) for n in layouts]
    all_nodes = nodes[1:]
    messages: list[Message] = [
        Message(frame_id=NMT_COB_ID, name="NMT", length=2, senders=[HOST],
                comment="NMT node control: command to one node, or to all with NodeId 0",
                signals=[
                    _signal("Command", 0, 8, False, all_nodes, choices=NMT_COMMAND_NAMES,
                            comment="NMT command specifier"),
                    _signal("NodeId", 8, 8, False, all_nodes,
                            comment="addressed node, 0 = all nodes"),
                ]),
        Message(frame_id=SYNC_COB_ID, name="SYNC", length=0, signals=[], senders=[HOST],
                cycle_time=round(1000.0 / rate_hz),
                comment="SYNC: drives apply their cyclic RPDOs and send their cyclic TPDOs"),
    ]
    for layout in layouts:
        for pdo in layout.plan.rpdos:
            messages.append(pdo_message(layout, pdo, False, rate_hz))
        for pdo in layout.plan.tpdos + layout.health.pdos:
            messages.append(pdo_message(layout, pdo, True, rate_hz))
    for layout in layouts:
        node = node_name(layout.node_id)
        messages.append(Message(
            frame_id=_emcy_cob_id(layout), name=f"EMCY_node{layout.node_id}", length=8,
            senders=[node], comment=f"node {layout.node_id}: emergency (CiA 301)",
            signals=[
                _signal("ErrorCode", 0, 16, False, [HOST], choices=EMCY_CODES,
                        comment="emergency error code (CiA 301 / CiA 402)"),
                _signal("ErrorRegister", 16, 8, False, [HOST], comment="error register 1001h"),
                _signal("ManufacturerData", 24, 40, False, [HOST],
                        comment="manufacturer-specific error data"),
            ]))
    heartbeats = [(layout.node_id, node_name(layout.node_id), f"node{layout.node_id}",
                   f"node {layout.node_id}") for layout in layouts]
    heartbeats.append((cfg.chassis.host_node_id, HOST, "host",
                       f"the host (node id {cfg.chassis.host_node_id})"))
    for node_id, sender, suffix, who in heartbeats:
        receivers = all_nodes if sender == HOST else [HOST]
        messages.append(Message(
            frame_id=HEARTBEAT_BASE + node_id, name=f"Heartbeat_{suffix}", length=1,
            senders=[sender],
            cycle_time=heartbeat_ms, comment=f"heartbeat of {who}",
            signals=[_signal("NmtState", 0, 7, False, receivers, choices=NMT_STATES,
                             comment="NMT state; bit 7 is node guarding's toggle bit")]))
    messages.sort(key=lambda m: m.frame_id)
    return cantools.database.Database(
        messages=messages,
        nodes=[Node(name) for name in nodes],
        version="",
    )


def dbc_text(cfg: ChassisConfig | None = None) -> str:
    header = ("Generated by omnican.plan.dbc (tools/gen_dbc.py) from the EDS files via "
              "omnican.plan.node; do not edit by hand")
    db = build_database(cfg)
    # Signals in PDO order; LF line ends (cantools mixes in CRLF).
    text: str = db.as_dbc_string(sort_signals=None).replace("\r\n", "\n")
    return text.replace("\nCM_ ", f'\nCM_ "{header}";\nCM_ ', 1)


_built: list[tuple[ChassisConfig, Any]] = []  # the last config's database, kept


def database_for(cfg: ChassisConfig) -> Any:
    """:func:`build_database` of ``cfg``, built once (about a second of CPU): a front
    end asks for it before the control loop runs, the telemetry when it decodes."""
    for known, db in _built:
        if known is cfg:
            return db
    db = build_database(cfg)
    _built[:] = [(cfg, db)]
    return db
