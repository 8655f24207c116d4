"""The simulated ground slips (omnican.sim.slip): the truth moves by what the ground takes,
the encoders still count every turn of the rims; a slip that starts changes what the
ground takes from then on; a roller that gives way turns the base; a ramp makes it creep."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import Chassis
from omnican.clock import SimClock
from omnican.core.kinematics import OmniKinematics
from omnican.sim.slip import SimSlip, Surface, set_slip
from tests.support.helpers import lockstep_rig

KIN = OmniKinematics.from_layout("b21", 0.19)


def drive(clock: SimClock, base: Chassis, vx: float, vy: float, wz: float,
          seconds: float) -> None:
    end = clock.now() + seconds
    while clock.now() < end:
        base.set_velocity(vx, vy, wz)
        clock.sleep(0.01)


def enabled(clock: SimClock, base: Chassis) -> None:
    deadline = clock.now() + 10.0
    while not base.status.enabled and clock.now() < deadline:
        clock.sleep(0.01)
    assert base.status.enabled


def test_a_slipping_wheel_turns_the_truth_not_the_encoders(channel: str) -> None:
    with lockstep_rig(channel) as (clock, sim, base):
        enabled(clock, base)
        drive(clock, base, 0.4, 0.0, 0.0, 1.0)
        before_true, before_odo = sim.true_pose, base.pose
        assert abs(before_true.theta) < 1e-3  # no slip yet: a straight line
        set_slip(sim, SimSlip(ratios=(0.0, 0.2, 0.0)))
        after_set = sim.true_pose
        assert after_set.distance_to(before_true) < 0.01  # no jump when it starts
        drive(clock, base, 0.4, 0.0, 0.0, 1.0)
        drive(clock, base, 0.0, 0.0, 0.0, 0.5)
        true, odo = sim.true_pose, base.pose
        assert abs(odo.theta - before_odo.theta) < 0.01  # the encoders: straight on
        # wheel 1 (at -60 deg) lost 20 % of its rim's motion: the base turned
        assert abs(true.theta - before_true.theta) > 0.1


def test_a_surface_slips_only_under_the_base() -> None:
    slip = SimSlip(ratios=(0.0, 0.0, 0.0), surfaces=(Surface(1.0, -1.0, 2.0, 1.0, 0.3),))
    assert slip.ratio(1, 0.5, 0.0) == 0.0
    assert slip.ratio(1, 1.5, 0.0) == 0.3
    with pytest.raises(ValueError, match="fraction 0-1"):
        SimSlip(ratios=(1.5,))


@given(st.integers(0, 2), st.floats(0.05, 0.5), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0))
def test_a_roller_that_gives_way_slides_its_contact_point_along_its_axis(
        wheel: int, give: float, vx: float, vy: float) -> None:
    rims = KIN.wheel_speeds_of(vx, vy, 0.0)
    dx, dy, dw = SimSlip(roller={wheel: give}).lateral(KIN, rims)
    beta = math.radians(KIN.drive_angles_deg[wheel])
    phi = math.radians(KIN.angles_deg[wheel])
    x, y = 0.19 * math.cos(phi), 0.19 * math.sin(phi)
    cx, cy = dx - dw * y, dy + dw * x  # the contact point's motion
    assert -math.sin(beta) * cx + math.cos(beta) * cy == pytest.approx(
        give * abs(rims[wheel]), abs=1e-9)
    # nothing along its drive direction: the encoder's reading stays the truth there
    assert math.cos(beta) * cx + math.sin(beta) * cy == pytest.approx(0.0, abs=1e-9)


def test_a_ramp_creeps_downhill() -> None:
    slip = SimSlip(ramp_grade_deg=10.0, ramp_downhill_deg=90.0)
    dx, dy = slip.creep(0.0, 1.0)
    assert dx == pytest.approx(0.0, abs=1e-12) and dy > 0.0
    assert SimSlip().creep(0.0, 1.0) == (0.0, 0.0)


def test_a_ramp_and_a_roller_move_the_simulated_base(channel: str) -> None:
    with lockstep_rig(channel) as (clock, sim, base):
        enabled(clock, base)
        set_slip(sim, SimSlip(ramp_grade_deg=10.0, ramp_downhill_deg=90.0, roller={0: 0.3}))
        drive(clock, base, 0.4, 0.0, 0.0, 1.0)
        drive(clock, base, 0.0, 0.0, 0.0, 0.5)
        true, odo = sim.true_pose, base.pose
        assert true.y > odo.y + 0.01  # crept downhill (+y) beyond what the wheels say
