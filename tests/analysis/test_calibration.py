"""omnican.analysis.calibration: the pure math (no bus, no threads)."""

from __future__ import annotations

import math
import sys
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from omnican import ConfigError, Odometry, OmniKinematics, Twist, default_config
from omnican.analysis.calibration import (
    Correction,
    FitRun,
    check_edited,
    edit_config_text,
    end_poses,
    fit,
    format_number,
    guided_correction,
    integrate,
    radius_factor_from_spin,
    render_config,
    scale_from_distance,
    scaled_kinematics,
    set_sim_table,
    sim_options,
    sim_truth,
    truth_options,
)
from omnican.config import WHEEL_EDS, SimTruth, parse_config

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

CFG = default_config()
KIN = CFG.kinematics()
PS = np.array([w.position_scale for w in CFG.wheels])
factor = st.floats(0.9, 1.1)

CONFIG_TEXT = """\
# The test robot. Comments and layout must survive calibration.
[bus]
interface = "virtual"   # keep me

[chassis]
layout = "b21"
base_radius = 0.19      # m, centre to wheel contact

[[wheel]]               # back
node_id = 1
gear_ratio = 16         # motor turns per wheel turn
encoder_cpr = 4096
wheel_radius = 0.05     # m

[[wheel]]               # right
node_id = 2
velocity_scale = -4772.44   # the seeds' k
position_scale = 48_000     # counts per m
base_radius = 0.2

[[wheel]]
node_id = 3
velocity_scale = 4772.44
position_scale = 48000.0
"""


def load_text(text: str):  # type: ignore[no-untyped-def]
    return parse_config(tomllib.loads(text), check_eds=False)


def true_counts(twists: list[Twist], dt: float, kin: OmniKinematics,
                factors: np.ndarray, scales: np.ndarray = PS) -> tuple[np.ndarray, np.ndarray]:
    """(counts (M, N), true end pose) of a base with geometry ``kin`` whose wheels turn
    ``factors`` times the configured counts per metre, driven by ``twists`` for ``dt`` each."""
    travel = np.vstack([np.zeros(kin.num_wheels),
                        np.cumsum([kin.to_wheel_speeds(t) * dt for t in twists], axis=0)])
    return travel * scales * factors, integrate(travel, kin)[-1]


# ---------------------------------------------------------------- guided


def test_scale_and_radius_formulas() -> None:
    # A wheel 3 % smaller than configured: 3 % more counts per metre, odometry over-reads.
    assert scale_from_distance(1.03, 1.0) == pytest.approx(1.03)
    # Corrected odometry angle 700 deg for a true 720: the base is smaller than configured.
    assert radius_factor_from_spin(math.radians(721), math.radians(720), 1.03) == \
        pytest.approx(721 / 1.03 / 720)
    c = guided_correction(3, 1.03, 1.0, 4.0, 4.0 / 1.03 / 1.02)
    assert c.wheel_factors == pytest.approx((1.03,) * 3)
    assert c.radius_factor == pytest.approx(1.02)


@pytest.mark.parametrize(("call", "message"), [
    (lambda: scale_from_distance(1.0, 0.0), "measured distance must be positive"),
    (lambda: scale_from_distance(0.0, 1.0), "odometry saw no straight motion"),
    (lambda: radius_factor_from_spin(1.0, -1.0), "opposite sign"),
    (lambda: radius_factor_from_spin(0.0, 1.0), "no rotation"),
    (lambda: Correction((1.0, -1.0, 1.0)), "positive and finite"),
])
def test_guided_bad_input(call, message: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=message):
        call()


@settings(deadline=None)
@given(s=factor, g=factor, distance=st.floats(0.2, 3.0), turns=st.floats(0.25, 4.0))
def test_guided_correction_recovers_a_wrong_base(s: float, g: float, distance: float,
                                                turns: float) -> None:
    """Straight then spin on a base with true scale s and radius g * R: the odometry of the
    configured base, corrected, reproduces the truth."""
    true_kin = scaled_kinematics(KIN, g)
    f = np.full(3, s)
    line, line_end = true_counts([Twist(distance, 0, 0)], 1.0, true_kin, f)
    spin, spin_end = true_counts([Twist(0, 0, 2 * math.pi * turns)], 1.0, true_kin, f)
    odo_line = integrate(line / PS, KIN)[-1]
    odo_spin = integrate(spin / PS, KIN)[-1]
    c = guided_correction(3, math.hypot(odo_line[0], odo_line[1]), distance, odo_spin[2],
                          spin_end[2])
    assert c.wheel_factors == pytest.approx((s,) * 3, rel=1e-9)
    assert c.radius_factor == pytest.approx(g, rel=1e-9)
    assert line_end[0] == pytest.approx(distance)
    # With the corrected config, odometry of the same counts is the truth.
    fixed = c.apply(CFG)
    fixed_ps = np.array([w.position_scale for w in fixed.wheels])
    np.testing.assert_allclose(integrate(spin / fixed_ps, fixed.kinematics())[-1], spin_end,
                               atol=1e-9)


def test_correction_apply_scales_everything_it_should() -> None:
    cfg = load_text(CONFIG_TEXT)
    c = Correction((1.1, 0.9, 1.0), 1.05)
    out = c.apply(cfg)
    assert [w.position_scale / v.position_scale for w, v in zip(out.wheels, cfg.wheels, strict=True)] == \
        pytest.approx([1.1, 0.9, 1.0])
    assert [w.velocity_scale / v.velocity_scale for w, v in zip(out.wheels, cfg.wheels, strict=True)] == \
        pytest.approx([1.1, 0.9, 1.0])
    assert out.chassis.base_radius == pytest.approx(0.1995)
    assert out.wheels[1].base_radius == pytest.approx(0.21)
    assert out.kinematics().base_radius == pytest.approx((0.1995, 0.21, 0.1995))


def test_truth_options() -> None:
    opts = truth_options(CFG, 0.03, -0.02)
    assert opts["true_scale"] == pytest.approx([1.03] * 3)
    assert opts["true_kinematics"].base_radius == pytest.approx((0.19 * 0.98,) * 3)
    assert truth_options(CFG, [0.01, 0.0, -0.01], 0.0)["true_scale"] == \
        pytest.approx([1.01, 1.0, 0.99])


def test_sim_truth_is_the_same_base_against_a_corrected_config() -> None:
    """The [sim] table holds the simulated base itself: against the config it was made
    from it is the errors given; against a corrected config, what is left of them."""
    truth = sim_truth(CFG, 0.03, -0.02)
    assert truth.base_radius == pytest.approx(0.19 * 0.98)
    opts = sim_options(CFG, truth)
    assert opts["true_scale"] == pytest.approx(truth_options(CFG, 0.03, -0.02)["true_scale"])
    assert opts["true_kinematics"].base_radius == pytest.approx((0.19 * 0.98,) * 3)
    corrected = Correction.common(3, 1.03, 0.98).apply(CFG)
    again = sim_options(corrected, truth)
    assert again["true_scale"] == pytest.approx([1.0] * 3)
    assert again["true_kinematics"].base_radius == pytest.approx(
        corrected.kinematics().base_radius)
    assert sim_options(CFG, SimTruth())["true_scale"] == [1.0] * 3  # none: as configured


def test_sim_table_is_appended_or_its_numbers_replaced() -> None:
    truth = SimTruth(0.2, (50000.0, 50000.0, 48000.5))
    appended = set_sim_table(CONFIG_TEXT, truth)
    assert appended.startswith(CONFIG_TEXT)
    assert load_text(appended).sim == truth
    own = CONFIG_TEXT + "\n[sim]   # my simulated robot\nbase_radius = 0.3  # worn\n# the end\n"
    replaced = set_sim_table(own, SimTruth(0.25, (7.0,) * 3))
    assert replaced.splitlines()[-4:] == ["[sim]   # my simulated robot", "base_radius = 0.25",
                                          "position_scale = 7.0", "# the end"]
    assert load_text(replaced).sim == SimTruth(0.25, (7.0,) * 3)
    assert load_text(replaced) == load_text(CONFIG_TEXT)  # the robot's numbers untouched
    # the tables under [sim] ([sim.slip], [sim.gyro]) are kept as they were
    grounds = CONFIG_TEXT + "\n[sim]\nbase_radius = 0.3\n\n[sim.slip]\nratio = 0.1\n"
    kept = load_text(set_sim_table(grounds, SimTruth(0.25, (7.0,) * 3))).sim
    assert kept is not None and kept.slip is not None and kept.slip.ratio == (0.1,) * 3
    assert (kept.base_radius, kept.position_scale) == (0.25, (7.0,) * 3)


@settings(max_examples=50)
@given(radius=st.floats(0.01, 10.0), scales=st.lists(st.floats(1e-6, 1e12), min_size=3,
                                                      max_size=3))
def test_sim_table_round_trips(radius: float, scales: list[float]) -> None:
    truth = SimTruth(radius, tuple(scales))
    text = set_sim_table(CONFIG_TEXT, truth)
    got = load_text(text).sim
    assert got is not None and got.base_radius == pytest.approx(radius, rel=1e-9)
    assert got.position_scale == pytest.approx(tuple(scales), rel=1e-9)
    assert set_sim_table(text, truth) == text  # written again: the same text


# ---------------------------------------------------------------- integration


@settings(max_examples=50)
@given(steps=st.lists(st.lists(st.floats(-0.05, 0.05), min_size=3, max_size=3), min_size=1,
                      max_size=50))
def test_integrate_is_odometry(steps: list[list[float]]) -> None:
    travel = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
    odo = Odometry(KIN)
    expected = [[p.x, p.y, p.theta] for p in (odo.update(row) for row in travel)]
    np.testing.assert_allclose(integrate(travel, KIN), expected, atol=1e-12)


def test_integrate_shapes() -> None:
    assert integrate(np.zeros((0, 3)), KIN).shape == (0, 3)
    assert integrate(np.ones((1, 3)), KIN).tolist() == [[0.0, 0.0, 0.0]]
    with pytest.raises(ValueError, match="travel must be"):
        integrate(np.zeros((4, 2)), KIN)


# ---------------------------------------------------------------- fit


def open_path(turn: float, heading: float) -> list[Twist]:
    """A straight leg along ``heading`` (body frame), then a spin of ``turn`` rad."""
    v = Twist(0.4 * math.cos(heading), 0.4 * math.sin(heading), 0.0)
    return [v] * 20 + [Twist(0, 0, turn)] * 20


@settings(max_examples=15, deadline=None)
@given(s=st.lists(factor, min_size=3, max_size=3), g=factor)
def test_fit_recovers_per_wheel_scales_and_radius(s: list[float], g: float) -> None:
    true_kin = scaled_kinematics(KIN, g)
    runs = []
    for k, (turn, heading) in enumerate([(3.0, 0.0), (-2.0, math.pi / 2), (2.5, 2.4)]):
        counts, end = true_counts(open_path(turn, heading), 0.05, true_kin, np.array(s))
        runs.append(FitRun(counts, tuple(end), f"run {k}"))  # type: ignore[arg-type]
    result = fit(runs, CFG)
    assert result.model == "wheels+radius"
    assert result.correction.wheel_factors == pytest.approx(s, rel=1e-6)
    assert result.correction.radius_factor == pytest.approx(g, rel=1e-6)
    assert np.max(np.abs(result.residual_after)) < 1e-8
    assert result.predicted_after == pytest.approx(np.array([r.measured for r in runs]),
                                                   abs=1e-8)


@settings(deadline=None)
@given(s=factor, g=factor)
def test_one_recording_fits_a_common_scale_and_the_radius(s: float, g: float) -> None:
    counts, end = true_counts(open_path(3.0, 0.3), 0.05, scaled_kinematics(KIN, g),
                              np.full(3, s))
    result = fit([FitRun(counts, tuple(end))], CFG)  # type: ignore[arg-type]
    assert result.model == "scale+radius"
    assert result.correction.wheel_factors == pytest.approx((s,) * 3, rel=1e-6)
    assert result.correction.radius_factor == pytest.approx(g, rel=1e-6)


def test_a_straight_line_says_nothing_about_the_radius() -> None:
    counts, end = true_counts([Twist(0.5, 0, 0)] * 10, 0.1, KIN, np.full(3, 1.05))
    result = fit([FitRun(counts, tuple(end))], CFG)  # type: ignore[arg-type]
    assert result.model == "scale"
    assert "do not determine" in result.note
    assert result.correction.wheel_factors == pytest.approx((1.05,) * 3, rel=1e-6)
    assert result.correction.radius_factor == 1.0


def test_fit_refuses_a_recording_without_motion() -> None:
    with pytest.raises(ValueError, match="do not determine any scale"):
        fit([FitRun(np.zeros((5, 3)), (0.0, 0.0, 0.0))], CFG)
    with pytest.raises(ValueError, match="no recordings"):
        fit([], CFG)
    with pytest.raises(ValueError, match="unknown model"):
        fit([FitRun(np.zeros((5, 3)), (0.0, 0.0, 0.0))], CFG, model="magic")


def test_fit_takes_wrapped_headings() -> None:
    """A measured heading given in (-pi, pi] after two turns still fits."""
    counts, end = true_counts(open_path(4 * math.pi + 0.3, 0.0), 0.05,
                              scaled_kinematics(KIN, 1.02), np.full(3, 0.97))
    wrapped = (end[0], end[1], math.remainder(end[2], 2 * math.pi))
    result = fit([FitRun(counts, wrapped)], CFG)  # type: ignore[arg-type]
    assert result.correction.radius_factor == pytest.approx(1.02, rel=1e-6)


def test_end_poses_without_samples() -> None:
    assert end_poses([FitRun(np.zeros((0, 3)), (0, 0, 0))], CFG,
                     Correction.common(3, 1.0)).tolist() == [[0, 0, 0]]


# ---------------------------------------------------------------- TOML text


def test_edit_keeps_comments_and_layout() -> None:
    c = Correction((1.25, 0.8, 1.0), 1.1)
    new = edit_config_text(CONFIG_TEXT, c)
    old_lines, new_lines = CONFIG_TEXT.splitlines(), new.splitlines()
    changed = [(a, b) for a, b in zip(old_lines, new_lines, strict=True) if a != b]
    assert len(old_lines) == len(new_lines)
    assert changed == [
        ("base_radius = 0.19      # m, centre to wheel contact",
         "base_radius = 0.209      # m, centre to wheel contact"),
        ("wheel_radius = 0.05     # m", "wheel_radius = 0.04     # m"),
        ("velocity_scale = -4772.44   # the seeds' k", "velocity_scale = -3817.952   # the seeds' k"),
        ("position_scale = 48_000     # counts per m", "position_scale = 38400.0     # counts per m"),
        ("base_radius = 0.2", "base_radius = 0.22"),
    ]
    check_edited(new, c.apply(load_text(CONFIG_TEXT)))


def test_edit_of_an_identity_correction_changes_nothing_that_loads() -> None:
    c = Correction.common(3, 1.0)
    new = edit_config_text(CONFIG_TEXT, c)
    assert load_text(new) == load_text(CONFIG_TEXT)


def test_check_edited_names_what_it_could_not_edit() -> None:
    inline = ('wheel = [{node_id = 1, velocity_scale = 10.0, position_scale = 20.0},\n'
              '         {node_id = 2, velocity_scale = 10.0, position_scale = 20.0},\n'
              '         {node_id = 3, velocity_scale = 10.0, position_scale = 20.0}]\n'
              '[chassis]\nlayout = "b21"\nbase_radius = 0.19\n')
    c = Correction.common(3, 1.1, 1.2)
    new = edit_config_text(inline, c)
    assert "base_radius = 0.228" in new  # what it could edit, it did
    with pytest.raises(ConfigError, match=r"could not correct wheel\[0\]\.velocity_scale in "
                                          r"x\.toml automatically .* set it to 11\.0 by hand"):
        check_edited(new, c.apply(load_text(inline)), "x.toml")
    with pytest.raises(ConfigError, match=r"the corrected x\.toml does not load"):
        check_edited("[chassis\n", c.apply(load_text(inline)), "x.toml")


def same_wheels(a, b) -> None:  # type: ignore[no-untyped-def]
    """Equal but for the 7 significant digits the scales are written with."""
    assert len(a) == len(b)
    for wa, wb in zip(a, b, strict=True):
        assert replace(wa, velocity_scale=0, position_scale=0) == \
            replace(wb, velocity_scale=0, position_scale=0)
        assert (wa.velocity_scale, wa.position_scale) == \
            pytest.approx((wb.velocity_scale, wb.position_scale), rel=1e-6)


def test_render_round_trips() -> None:
    cfg = replace(default_config(), chassis=replace(default_config().chassis, rate_hz=250.0,
                                                    max_accel=2.0, stop_decel=4.0,
                                                    heartbeat_ms=50))
    text = render_config(cfg, "line one\nline two")
    assert text.startswith("# line one\n# line two\n")
    back = load_text(text)
    assert back.chassis == cfg.chassis
    same_wheels(back.wheels, cfg.wheels)
    assert "stop_decel" not in text  # the default for max_accel 2


def test_render_keeps_what_the_drives_report_and_their_settings() -> None:
    """A calibrated config written back keeps the health objects, [[wheel.sdo]], [power]
    and [estop] as they were."""
    from omnican.config import EstopSettings, PowerSettings, SdoWrite

    base = default_config()
    wheels = (replace(base.wheels[0], current="0x30D1:02", current_scale=0.001, torque="",
                      sdo_writes=(SdoWrite("0x2000:00", 500),
                                  SdoWrite("Some flag", True, "bool"))),
              *base.wheels[1:])
    cfg = replace(base, wheels=wheels, power=PowerSettings(cutoff_v=21.5, delay_s=2.0),
                  estop=EstopSettings(bit=14, object="0x6041", active_low=True, node_id=2))
    back = load_text(render_config(cfg))
    same_wheels(back.wheels, cfg.wheels)
    assert (back.power, back.estop) == (cfg.power, cfg.estop)


def test_render_custom_geometry() -> None:
    text = CONFIG_TEXT.replace('layout = "b21"\n', "").replace("node_id = 1\n",
                                                               "node_id = 1\nangle_deg = 180\n")
    text = text.replace("node_id = 2\n", "node_id = 2\nangle_deg = -60\nmode = \"csv\"\n")
    text = text.replace("node_id = 3\n", f"node_id = 3\nangle_deg = 60\neds = \"{WHEEL_EDS}\"\n")
    cfg = load_text(text)
    back = load_text(render_config(cfg))
    same_wheels(back.wheels, cfg.wheels)
    assert back.kinematics().matrix.tolist() == cfg.kinematics().matrix.tolist()


@given(st.floats(1e-6, 1e9) | st.floats(-1e9, -1e-6))
def test_format_number_is_a_close_toml_float(value: float) -> None:
    text = format_number(value)
    parsed = tomllib.loads(f"x = {text}")["x"]
    assert isinstance(parsed, float)
    assert parsed == pytest.approx(value, rel=1e-6)
