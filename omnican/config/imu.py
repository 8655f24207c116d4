"""The ``[imu]`` and ``[sim.gyro]`` tables: checked against the schema, and for a CAN IMU
against its DBC file (the file read, the message and signals it names there, units
known), so that ``omnican check-config`` says what is wrong in one line before anything
opens a bus.

No I/O beyond reading the DBC file the table names.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omnican.config.model import ImuSettings, SimGyro
from omnican.config.reader import Reader, suggest, whole_path
from omnican.config.schema import IMU_SOURCES
from omnican.core.imu import accel_unit, rate_unit
from omnican.errors import ConfigError

#: The keys only a CAN IMU reads, and those only a topic's.
CAN_KEYS = ("dbc", "message", "yaw_rate", "yaw_rate_unit", "accel_message", "accel_x",
            "accel_y", "accel_unit")
TOPIC_KEYS = ("topic",)


class DbcError(ConfigError):
    """What is wrong between an ``[imu]`` table and its DBC; ``key``: the key to fix."""

    def __init__(self, message: str, key: str) -> None:
        super().__init__(message)
        self.key = key


def parse_imu(r: Reader, table: Any, base_dir: Path | None) -> ImuSettings:
    """The ``[imu]`` table as :class:`ImuSettings`; a CAN IMU's DBC read and checked."""
    t = r.table("imu", table, "imu")
    source = t["source"]
    if source not in IMU_SOURCES:
        raise r.fail("imu.source", f"must be one of {', '.join(IMU_SOURCES)}, got {source!r}")
    given = set(table)
    if source == "can":
        for key in ("dbc", "message", "yaw_rate"):
            if t[key] is None:
                raise r.fail(f"imu.{key}", "missing: a CAN IMU names its DBC, the message and "
                             "the yaw rate's signal")
        if (t["accel_x"] is None) != (t["accel_y"] is None):
            raise r.fail("imu.accel_x" if t["accel_x"] is None else "imu.accel_y",
                         "give both accelerations' signals or neither")
        stray = sorted(given & set(TOPIC_KEYS))
    else:
        stray = sorted(given & set(CAN_KEYS))
    if stray:
        raise r.fail(f"imu.{stray[0]}", f"not read for source {source!r}")
    if not t["topic"].startswith("/") or t["topic"] == "/":
        raise r.fail("imu.topic", f"must be a topic's full name, e.g. \"/imu/data\", got "
                     f"{t['topic']!r}")
    for key, known in (("yaw_rate_unit", rate_unit), ("accel_unit", accel_unit)):
        if t[key] is not None and known(t[key]) is None:
            units = "deg/s, rad/s" if key == "yaw_rate_unit" else "m/s^2, g"
            raise r.fail(f"imu.{key}", f"unknown unit {t[key]!r} (known: {units})")
    dbc = _dbc_path(t["dbc"], base_dir)
    imu = ImuSettings(
        source=source, dbc=Path(dbc) if dbc is not None else None, message=t["message"],
        yaw_rate=t["yaw_rate"], yaw_rate_unit=t["yaw_rate_unit"],
        accel_message=t["accel_message"], accel_x=t["accel_x"], accel_y=t["accel_y"],
        accel_unit=t["accel_unit"], topic=t["topic"],
        mount_yaw_deg=float(t["mount_yaw_deg"]), upside_down=t["upside_down"],
        stale_s=float(t["stale_s"]))
    if source == "can":
        try:
            dbc_imu(imu)
        except DbcError as exc:
            raise r.fail(f"imu.{exc.key}", str(exc)) from None
    return imu


#: The DBC files omnican ships (a config may name one by its bare name).
BUNDLED_DBC = Path(__file__).resolve().parents[1] / "dbc"


def _dbc_path(name: str | None, base_dir: Path | None) -> str | None:
    """The DBC a config names, made whole against the config's folder; a bare name that
    is not there but is one omnican ships (``openimu300ri.dbc``): the bundled file."""
    path = whole_path(name, base_dir)
    if name is None or path is None or Path(path).exists() or Path(name).name != name:
        return path
    bundled = BUNDLED_DBC / name
    return str(bundled) if bundled.is_file() else path


def parse_sim_gyro(r: Reader, table: Any) -> SimGyro:
    """The ``[sim.gyro]`` table as :class:`SimGyro`."""
    g = r.table("sim.gyro", table, "sim.gyro")
    return SimGyro(enabled=g["enabled"], rate_hz=float(g["rate_hz"]),
                   bias_deg_s=float(g["bias_deg_s"]), drift_deg_s=float(g["drift_deg_s"]),
                   noise_deg_s=float(g["noise_deg_s"]),
                   mount_yaw_deg=None if g["mount_yaw_deg"] is None
                   else float(g["mount_yaw_deg"]), noise_stream=g["noise_stream"])


@dataclass(frozen=True)
class DbcImu:
    """A CAN IMU as its DBC describes it: the cantools messages of the yaw rate and of the
    accelerations (None: none), and the factors to SI units (rad/s, m/s^2)."""

    rate_message: Any  # cantools.database.can.Message
    accel_message: Any | None
    rate_factor: float
    accel_factor: float


def dbc_imu(imu: ImuSettings) -> DbcImu:
    """Read ``imu.dbc`` and find what ``imu`` names in it. Raises :class:`DbcError` naming
    the ``[imu]`` key that is wrong."""
    import cantools

    if imu.dbc is None or imu.message is None or imu.yaw_rate is None:
        raise DbcError("a CAN IMU names its dbc, message and yaw_rate", "dbc")
    try:
        db = cantools.database.load_file(str(imu.dbc), database_format="dbc")
    except FileNotFoundError:
        raise DbcError(f"no such DBC file: {imu.dbc}", "dbc") from None
    except OSError as exc:
        raise DbcError(f"cannot read {imu.dbc}: {exc.strerror or exc}", "dbc") from None
    except Exception as exc:  # cantools' parse errors have no common base
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DbcError(f"{imu.dbc} is not a DBC file cantools reads: {first[:120]}",
                          "dbc") from None
    rate_msg = _message(db, imu.message, "message")
    rate_sig = _signal(rate_msg, imu.yaw_rate, "yaw_rate")
    rate_factor = _factor(imu.yaw_rate_unit, rate_sig, rate_unit, "yaw_rate_unit",
                          "deg/s or rad/s")
    accel_msg = None
    accel_factor = 1.0
    if imu.accel_x is not None and imu.accel_y is not None:
        accel_msg = (_message(db, imu.accel_message, "accel_message")
                     if imu.accel_message is not None else rate_msg)
        sig_x = _signal(accel_msg, imu.accel_x, "accel_x")
        sig_y = _signal(accel_msg, imu.accel_y, "accel_y")
        accel_factor = _factor(imu.accel_unit, sig_x, accel_unit, "accel_unit", "m/s^2 or g")
        if sig_y.unit != sig_x.unit and imu.accel_unit is None:
            raise DbcError(f"signals {sig_x.name} and {sig_y.name} have different units "
                              f"({sig_x.unit!r}, {sig_y.unit!r}): name one", "accel_unit")
    return DbcImu(rate_msg, accel_msg, rate_factor, accel_factor)


def _message(db: Any, name: str, key: str) -> Any:
    names = [m.name for m in db.messages]
    if name not in names:
        raise DbcError(f"no message {name!r} in the DBC{_known(name, names)}", key)
    return db.get_message_by_name(name)


def _signal(message: Any, name: str, key: str) -> Any:
    names = [s.name for s in message.signals]
    if name not in names:
        raise DbcError(f"no signal {name!r} in message {message.name}"
                       f"{_known(name, names)}", key)
    return message.get_signal_by_name(name)


def _known(name: str, names: list[str]) -> str:
    """" (did you mean 'x'?)", else the names the DBC has (the first few)."""
    close = suggest(name, names)
    if "did you mean" in close:
        return close
    shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
    return f" (it has: {shown})" if names else " (it has none)"


def _factor(given: str | None, signal: Any, known: Any, key: str, what: str) -> float:
    """SI per unit of ``signal``: the unit the config gives, else the DBC's."""
    unit = given if given is not None else signal.unit or ""
    factor: float | None = known(unit)
    if factor is None:
        said = f"its unit {unit!r} is not one omnican knows" if unit else "it has no unit"
        raise DbcError(f"the DBC's signal {signal.name}: {said}; give {key} ({what})", key)
    return factor


def describe(imu: ImuSettings) -> str:
    """One line of what an ``[imu]`` table reads (``omnican check-config``)."""
    mount = (f"mounted {imu.mount_yaw_deg:g} deg"
             + (", upside down" if imu.upside_down else "")
             + f"; silent after {imu.stale_s:g} s")
    if imu.source != "can":
        return f"imu: sensor_msgs/Imu on {imu.topic} ({imu.source}), {mount}"
    dbc = dbc_imu(imu)
    msg = dbc.rate_message
    bits = "29-bit" if msg.is_extended_frame else "11-bit"
    unit = imu.yaw_rate_unit or msg.get_signal_by_name(imu.yaw_rate).unit
    line = (f"imu: CAN message {msg.name} (0x{msg.frame_id:X}, {bits}) of "
            f"{imu.dbc.name if imu.dbc else '?'}, yaw rate {imu.yaw_rate} in {unit}")
    if dbc.accel_message is not None:
        line += f", accelerations {imu.accel_x}, {imu.accel_y} of {dbc.accel_message.name}"
    return f"{line}; {mount}"
