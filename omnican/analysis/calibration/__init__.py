"""Calibration math: wheel scales and base radius from odometry against measurements,
and the corrected config as TOML text.

Two unknowns per wheel matter to odometry: how many encoder counts one metre of rim
travel really is, and how far the wheels really sit from the centre. Both are
expressed as factors on the config (a :class:`Correction`):

* ``s_i`` = true counts per metre / configured ``position_scale`` of wheel ``i`` (a
  wheel worn smaller than configured has ``s_i > 1``: it turns more counts per metre,
  so the odometry over-reads distance by ``s_i``). The corrected ``position_scale``
  and ``velocity_scale`` are both multiplied by ``s_i`` (a drive velocity unit is a
  fixed number of counts per second); a config giving ``wheel_radius`` instead
  divides it by ``s_i``.
* ``g`` = true base radius / configured base radius.

Guided calibration (:func:`guided_correction`): a straight run gives the common scale
``s = d_odo / d_true`` (translation does not involve the radius); a spin then gives
``g = (theta_odo / s) / theta_true``: with corrected scales the odometry would have
read ``theta_odo / s``, and for a given wheel travel the turned angle is inversely
proportional to the radius.

Fit (:func:`fit`): Gauss-Newton least squares of the end poses predicted by integrating
the recorded counts with candidate factors against measured end poses (3 equations per
recording). Pure: numpy only, no I/O.

The parts, each importable from here:

- :mod:`~omnican.analysis.calibration.correction`: the correction, the digits the
  measurements support, the guided calibration, and the simulated base that is a given
  correction off;
- :mod:`~omnican.analysis.calibration.fit`: the odometry of recorded counts, vectorised,
  and the fit;
- :mod:`~omnican.analysis.calibration.config_edit`: the corrected config as TOML text.
"""

from omnican.analysis.calibration.config_edit import (
    SIM_DIGITS,
    ConfigEdit,
    check_edited,
    check_sim,
    edit_config,
    edit_config_text,
    format_number,
    render_config,
    set_sim_table,
)
from omnican.analysis.calibration.correction import (
    ANGLE_RESOLUTION_RAD,
    DISTANCE_RESOLUTION_M,
    Correction,
    guided_correction,
    measured_digits,
    radius_factor_from_spin,
    scale_from_distance,
    scaled_kinematics,
    sim_options,
    sim_truth,
    truth_options,
)
from omnican.analysis.calibration.fit import (
    MODELS,
    FitResult,
    FitRun,
    FloatArray,
    end_poses,
    fit,
    integrate,
)

__all__ = [
    "ANGLE_RESOLUTION_RAD",
    "DISTANCE_RESOLUTION_M",
    "MODELS",
    "SIM_DIGITS",
    "ConfigEdit",
    "Correction",
    "FitResult",
    "FitRun",
    "FloatArray",
    "check_edited",
    "check_sim",
    "edit_config",
    "edit_config_text",
    "end_poses",
    "fit",
    "format_number",
    "guided_correction",
    "integrate",
    "measured_digits",
    "radius_factor_from_spin",
    "render_config",
    "scale_from_distance",
    "scaled_kinematics",
    "set_sim_table",
    "sim_options",
    "sim_truth",
    "truth_options",
]
