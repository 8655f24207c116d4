"""The simulated drive's axis motion on its own: a LocalNode's dictionary, no bus, and
time passed by hand."""

from __future__ import annotations

import math
import random
from pathlib import Path

import canopen
import pytest

from omnican import WHEEL_EDS
from omnican.protocol import cia402
from omnican.protocol.cia402 import State
from omnican.protocol.object_map import AxisObjects, Obj
from omnican.sim.axis import COAST_TAU_S, Axis, Motion, group_axes, supported_modes
from omnican.sim.stage import PowerStage
from tests.support.helpers import VENDOR_EDS


class Rig:
    """One drive's motion, its dictionary written the way the drive's hooks would."""

    def __init__(self, eds: Path = WHEEL_EDS, cpu: float = 10.0, initial: float = 0.0) -> None:
        self.node = canopen.LocalNode(1, str(eds))
        d = self.node.object_dictionary
        n = max(1, AxisObjects(d, 0).num_axes)
        self.groups, self.axes = group_axes(d, [cpu] * n, [initial] * n, PowerStage, eds.name)
        self.motion = Motion(d, self.groups, self.node.data_store, self.node.get_data,
                             tau_s=0.0, encoder_noise=0.0, rng=random.Random(1),
                             initial_position=[initial] * n, start=0.0)
        self.motion.load_window()
        self.t = 0.0

    def write(self, ax: Axis, obj: Obj, value: int) -> None:
        entry = ax.objs[obj]
        self.write_raw(entry.index, entry.subindex, entry.encode(value))

    def write_raw(self, index: int, subindex: int, data: bytes) -> None:
        self.node.data_store.setdefault(index, {})[subindex] = data
        self.motion.written(index, subindex)

    def enable(self, mode: int = 3) -> None:
        for group in self.groups:
            assert group.mode_entry is not None
            group.mode = mode
            group.stage.state = State.OPERATION_ENABLED
        self.motion.invalidate()

    def wait(self, seconds: float) -> None:
        self.t += seconds
        assert self.motion.advance(self.t)

    def units(self, ax: Axis) -> float:
        return ax.state.velocity / ax.counts_per_unit


@pytest.mark.parametrize(("eds", "shape"), [
    (WHEEL_EDS, [1]),
    (VENDOR_EDS / "roboteq_v80_21.eds", [1, 1, 1]),  # a controlword per axis (+0x800)
    (VENDOR_EDS / "zlac8015d.eds", [2]),  # two axes as sub-indices, one controlword
])
def test_axes_are_grouped_by_their_controlword(eds: Path, shape: list[int]) -> None:
    rig = Rig(eds)
    assert [len(g.axes) for g in rig.groups] == shape
    assert [ax.number for ax in rig.axes] == list(range(sum(shape)))
    assert all(ax.group.axes.count(ax) == 1 for ax in rig.axes)
    assert len({(g.controlword.index, g.controlword.subindex) for g in rig.groups}) == len(shape)


def test_supported_modes_come_from_6502_or_from_the_objects_present() -> None:
    bundled = canopen.LocalNode(1, str(WHEEL_EDS)).object_dictionary
    assert supported_modes(bundled) == {2, 3, 9}
    zlac = canopen.LocalNode(1, str(VENDOR_EDS / "zlac8015d.eds")).object_dictionary
    assert 3 in supported_modes(zlac) and 9 not in supported_modes(zlac)  # 6060h allows 1-4


def test_profile_velocity_ramps_to_the_target_and_says_so() -> None:
    rig = Rig(cpu=10.0)
    ax = rig.axes[0]
    group = ax.group
    rig.write(ax, Obj.PROFILE_ACCEL, 1000)  # units/s^2
    rig.write(ax, Obj.PROFILE_DECEL, 2000)
    rig.write_raw(0x606D, 0, (10).to_bytes(4, "little"))  # velocity window: 10 units
    assert rig.motion.window == 10
    rig.enable()
    rig.write(ax, Obj.TARGET_VELOCITY, 500)
    rig.wait(0.25)
    assert rig.units(ax) == pytest.approx(250.0)
    assert not rig.motion.status_bits(group) & cia402.SW_TARGET_REACHED
    assert rig.motion.velocity(ax) == 250
    rig.wait(0.5)
    assert rig.units(ax) == pytest.approx(500.0)
    assert rig.motion.status_bits(group) & cia402.SW_TARGET_REACHED
    assert not rig.motion.status_bits(group) & cia402.SW_OMS_12  # not at speed zero
    group.stage.controlword = 0x10F  # halt: down on the profile deceleration
    rig.motion.invalidate()
    rig.wait(0.125)
    assert rig.units(ax) == pytest.approx(250.0)
    assert not rig.motion.status_bits(group) & cia402.SW_TARGET_REACHED  # halted: 0 is the goal
    rig.wait(0.25)
    assert rig.motion.standstill(group)
    bits = rig.motion.status_bits(group)
    assert bits & cia402.SW_TARGET_REACHED and bits & cia402.SW_OMS_12


def test_a_target_beyond_the_max_profile_velocity_is_limited() -> None:
    rig = Rig(cpu=1.0)
    ax = rig.axes[0]
    rig.write(ax, Obj.MAX_PROFILE_VELOCITY, 300)
    rig.enable()
    rig.write(ax, Obj.TARGET_VELOCITY, -1000)
    rig.wait(0.1)
    assert rig.units(ax) == pytest.approx(-300.0)
    assert rig.motion.status_bits(ax.group) & cia402.SW_INTERNAL_LIMIT


def test_quick_stop_ramps_on_its_deceleration_and_a_disabled_axis_coasts() -> None:
    rig = Rig(cpu=1.0)
    ax = rig.axes[0]
    rig.write(ax, Obj.QUICK_STOP_DECEL, 2000)
    rig.enable(mode=9)  # csv: no ramp of its own
    rig.write(ax, Obj.TARGET_VELOCITY, 1000)
    rig.wait(0.01)
    assert rig.motion.status_bits(ax.group) & cia402.SW_OMS_12  # csv: following the command
    ax.group.stage.state = State.QUICK_STOP_ACTIVE
    rig.motion.invalidate()
    rig.wait(0.25)
    assert rig.units(ax) == pytest.approx(500.0)
    ax.group.stage.state = State.SWITCH_ON_DISABLED  # no torque: it spins down freely
    rig.motion.invalidate()
    rig.wait(COAST_TAU_S)
    assert rig.units(ax) == pytest.approx(500.0 / math.e)


def test_the_counter_wraps_like_an_encoder_and_restarts_at_power_up() -> None:
    rig = Rig(cpu=1.0, initial=2**31 - 100)
    ax = rig.axes[0]
    position = rig.motion.readers()[(0x6064, 0)]
    assert position() == 2**31 - 100
    rig.enable(mode=9)
    rig.write(ax, Obj.TARGET_VELOCITY, 1000)
    rig.wait(0.5)
    assert position() == -(2**31) + 400  # 500 counts on: wrapped to negative
    assert ax.state.position == pytest.approx(500.0)  # the wheel itself never wraps
    rig.motion.power_up()
    assert position() == 2**31 - 100
    rig.motion.restart_ramps(ax.group)  # enabled again: the ramp starts at the wheel's speed
    assert ax.state.demand == ax.state.velocity


def test_a_new_target_keeps_the_axis_parameters_anything_else_drops_them() -> None:
    rig = Rig()
    ax = rig.axes[0]
    rig.enable()
    rig.wait(0.01)
    params = ax.params
    assert params is not None and ax.command is not None
    rig.write(ax, Obj.TARGET_VELOCITY, 100)
    assert ax.params is params and ax.command is None
    rig.write(ax, Obj.PROFILE_ACCEL, 100)
    assert ax.params is None
