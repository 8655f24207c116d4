"""What a simulated drive knows about itself beyond its motion: the motor current and
torque, the DC link voltage, the motor temperature, a following error, the digital
inputs (the e-stop), and the conditions injected into it.

The values come from :mod:`omnican.sim.electrical` applied to each axis's motion.
They are served in CiA 402's standard objects where the drive's EDS has them (6077h
and 6078h per mille of the rated current 6075h, 6079h in mV, 60F4h, 60FDh) and in the
vendor objects a robot config names (``signals``: object -> quantity, axis and SI units
per unit, as the config reads them: the simulator does not know a vendor's units).

The e-stop is wired to one input of every drive: a bit of 60FDh (by default bit 16,
"digital input 1"), or a statusword bit (a drive reporting its safe torque off there).
Pressed, it also takes the power stage's torque away (safe torque off): the stage
drops to SWITCH ON DISABLED and cannot be enabled until it is released.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial

from canopen import objectdictionary as od

from omnican.plan.health_fields import HEALTH_FIELDS
from omnican.protocol import cia402
from omnican.protocol.object_map import Entry, Obj, entry_at
from omnican.sim import electrical
from omnican.sim.axis import DEFAULT_TAU_S, Axis, AxisGroup
from omnican.sim.pdo import Getter, read_uint

Key = tuple[int, int]
Reader = Callable[[], int]

#: 60FDh bit the simulator's e-stop is wired to unless a config says otherwise.
ESTOP_INPUT_BIT = 16
WARM_EVERY_S = 0.1  # temperatures are integrated in steps of at least this (tau: minutes)
DEFAULT_COUNTS_PER_M = 10_000.0  # a drive on its own (no base says how its wheel rolls)
#: What a config may name a vendor object for: what a drive reports (but a register,
#: which the simulator serves as 1001h), by the health plan's word.
QUANTITIES = tuple(f.quantity for f in HEALTH_FIELDS if not f.register)
_STATUSWORD = int(Obj.STATUSWORD)


@dataclass(frozen=True)
class EstopInput:
    """Where the e-stop shows: bit ``bit`` of object ``index:subindex``, set while pressed
    (clear while pressed when ``active_low``: a normally closed loop)."""

    index: int = int(Obj.DIGITAL_INPUTS)
    subindex: int = 0
    bit: int = ESTOP_INPUT_BIT
    active_low: bool = False


class DriveHealth:
    """The health objects of one simulated drive (see the module docstring).

    Args:
        dictionary: the drive's object dictionary.
        axes: its axes (their motion is read, and the injected conditions set on them).
        get_data: reads an object as an SDO upload would (6075h, the rated current).
        counts_per_m: encoder counts per metre at the rim, per axis.
        signals: vendor objects a config names: (index, sub) -> (quantity, axis, SI per
            unit), quantity one of :data:`QUANTITIES`.
        estop: where the e-stop shows.
        start: the time (s) the temperatures start at ambient.
    """

    def __init__(self, dictionary: od.ObjectDictionary, axes: Sequence[Axis], get_data: Getter,
                 *, counts_per_m: Sequence[float],
                 signals: Mapping[Key, tuple[str, int, float]] | None = None,
                 estop: EstopInput | None = None,
                 model: electrical.MotorModel = electrical.DEFAULT_MODEL,
                 start: float = 0.0) -> None:
        self._dictionary = dictionary
        self.axes = list(axes)
        self._get = get_data
        self.model = model
        self.counts_per_m = [abs(c) or DEFAULT_COUNTS_PER_M for c in counts_per_m]
        self._signals = dict(signals or {})
        self.estop_input = estop or EstopInput()
        self.supply_v = electrical.NOMINAL_SUPPLY_V
        self.estop_pressed = False
        self.temperature_c = [model.ambient_c] * len(self.axes)
        self.following_error: list[int | None] = [None] * len(self.axes)
        self._warmed_at = start
        self._rated: float | None = None  # rated_current_a, as last read

    # ------------------------------------------------------------ the values (SI)

    def current_a(self, ax: Axis) -> float:
        """The motor current of ``ax`` now (A)."""
        st, per_m = ax.state, self.counts_per_m[ax.number]
        tau = ax.command[3] if ax.command is not None else DEFAULT_TAU_S
        accel = (st.demand - st.velocity) / tau if tau > 0 else 0.0
        return electrical.motor_current(
            self.model, st.velocity / per_m, accel / per_m, st.demand / per_m,
            powered=ax.group.stage.powered, grounded=ax.grounded, jammed=ax.jammed,
            pushed=ax.pushed_counts_s is not None)

    def voltage_v(self) -> float:
        """The DC link (V): the supply sagging under every axis's current."""
        return electrical.dc_link_voltage(self.model, self.supply_v,
                                          (self.current_a(ax) for ax in self.axes))

    def rated_current_a(self) -> float:
        """6075h (mA) as the drive holds it, else half the current limit (read from the
        dictionary once, again after :meth:`forget_rated`: a write of 6075h, a boot)."""
        rated = self._rated
        if rated is None:
            rated = self._rated = self._read_rated()
        return rated

    def forget_rated(self) -> None:
        """6075h may hold another value now (written, or the drive booted)."""
        self._rated = None

    def _read_rated(self) -> float:
        if isinstance(self._dictionary.get(int(Obj.RATED_CURRENT)), od.ODVariable):
            rated = read_uint(self._get, int(Obj.RATED_CURRENT), 0, "<I", 0) / 1000.0
            if rated > 0:
                return rated
        return self.model.limit_a / 2.0

    def warm(self, now: float) -> None:
        """Integrate the temperatures up to ``now`` (at the present currents)."""
        dt = now - self._warmed_at
        if dt < WARM_EVERY_S:
            return
        self._warmed_at = now
        for ax in self.axes:
            k = ax.number
            self.temperature_c[k] = electrical.temperature_after(
                self.model, self.temperature_c[k], self.current_a(ax), dt)

    def si_value(self, quantity: str, ax: Axis) -> float:
        """``quantity`` (one of :data:`QUANTITIES`) of ``ax`` now, in its unit (the
        table's: omnican.plan.health_fields). Raises ValueError for a value the
        simulator has no model of."""
        if quantity == "current":
            return self.current_a(ax)
        if quantity == "torque":  # percent of the rated torque
            return 100.0 * self.current_a(ax) / self.rated_current_a()
        if quantity == "voltage":
            return self.voltage_v()
        if quantity == "temperature":
            return self.temperature_c[ax.number]
        raise ValueError(f"the simulator has no model of a drive's {quantity}")

    # ------------------------------------------------------------ as objects

    def readers(self) -> dict[Key, Reader]:
        """The objects served: the standard ones the EDS has, per axis, then the
        vendor objects named in ``signals`` (which win where both name one)."""
        out: dict[Key, Reader] = {}
        for ax in self.axes:
            standard: tuple[tuple[Obj, Reader], ...] = (
                (Obj.CURRENT_ACTUAL, partial(self._per_mille_current, ax)),
                (Obj.TORQUE_ACTUAL, partial(self._per_mille_current, ax)),
                (Obj.DC_LINK_VOLTAGE, lambda: round(1000.0 * self.voltage_v())),
                (Obj.FOLLOWING_ERROR, partial(self._following_error, ax)),
            )
            for obj, reader in standard:
                entry = ax.objs.get(obj)
                if entry is not None:
                    out[(entry.index, entry.subindex)] = _fitted(entry, reader)
        estop = self.estop_input
        if estop.index != int(Obj.STATUSWORD):
            out[(estop.index, estop.subindex)] = self._inputs
        for (index, sub), (quantity, axis, scale) in self._signals.items():
            ax = self.axes[min(axis, len(self.axes) - 1)]
            out[(index, sub)] = _fitted(entry_at(self._dictionary, index, sub),
                                        partial(self._scaled, quantity, ax, scale))
        return out

    def _per_mille_current(self, ax: Axis) -> int:
        return electrical.per_mille(self.current_a(ax), self.rated_current_a())

    def _following_error(self, ax: Axis) -> int:
        return self.following_error[ax.number] or 0

    def _scaled(self, quantity: str, ax: Axis, scale: float) -> int:
        return round(self.si_value(quantity, ax) / scale) if scale else 0

    def _inputs(self) -> int:
        """The e-stop's input object: its bit as the loop says (other inputs low)."""
        estop = self.estop_input
        return (1 << estop.bit) if self.estop_pressed != estop.active_low else 0

    def statusword_bits(self, group: AxisGroup) -> int:
        """Bits of 6041h this adds: 13 (following error, pv's "max slippage error") while
        one is injected, and the e-stop where it is wired to the statusword."""
        sw = 0
        following = self.following_error
        for ax in group.axes:
            if following[ax.number]:
                sw = cia402.SW_OMS_13
                break
        estop = self.estop_input
        if estop.index == _STATUSWORD and self.estop_pressed != estop.active_low:
            sw |= 1 << estop.bit
        return sw


def _fitted(entry: Entry, reader: Reader) -> Reader:
    """``reader`` as the object's raw integer: saturated to the range of the quantity
    (signed where it is, whatever the EDS declares), two's complement for a type the EDS
    declares unsigned."""
    bits = entry.bits
    lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if entry.signed else (0, (1 << bits) - 1)
    full = 1 << bits

    def fitted() -> int:
        value = max(lo, min(hi, reader()))
        return value if entry.declared_signed else value % full

    return fitted
