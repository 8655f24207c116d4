"""Names that moved keep working for one release, each with a DeprecationWarning naming
its new home: ``omnican.motion``, ``omnican.teleop_model`` and ``omnican.slamware``
(which went with the layers' restructure without one: issue 36, item 16)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from omnican.layers import FACE
from tests.support.helpers import ROOT

MOVED = {"motion": "command.motion", "teleop_model": "command.teleop",
         "slamware": "protocol.slamware"}

PROBE = """
import importlib, json, sys, warnings
old, new, form = sys.argv[1:]
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    import omnican
    quiet = [str(w.message) for w in caught]
    if form == "from":
        module = getattr(__import__("omnican", fromlist=[old]), old)
    else:
        module = importlib.import_module(f"omnican.{old}")
print(json.dumps({"same": module is importlib.import_module(f"omnican.{new}"),
                  "quiet": quiet,
                  "warned": [[w.category.__name__, str(w.message)] for w in caught]}))
"""


@pytest.mark.parametrize("form", ["from", "import"])
@pytest.mark.parametrize("old", sorted(MOVED))
def test_a_moved_name_is_the_new_module_with_a_warning(old: str, form: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", PROBE, old, MOVED[old], form],
                         capture_output=True, text=True, env=env, timeout=60, check=True)
    seen = json.loads(out.stdout)
    assert seen["same"]
    assert seen["quiet"] == []  # import omnican alone warns of nothing
    assert seen["warned"] == [[
        "DeprecationWarning", f"omnican.{old} moved to omnican.{MOVED[old]}; the old name "
        "goes in the next release"]]


def test_the_moved_names_are_the_face_s() -> None:
    assert set(MOVED) == FACE - {"__init__", "__main__"}


# -- the front ends' tables, one typed table of the config since issue 39 ---------------

EXAMPLE = ROOT / "examples" / "robot.toml"


def test_a_front_ends_table_under_its_old_name_warns_and_is_the_same(tmp_path: object
                                                                       ) -> None:
    from pathlib import Path

    from omnican.config import load_config

    path = Path(str(tmp_path)) / "robot.toml"
    path.write_text(EXAMPLE.read_text() + '\n[zenoh]\nnamespace = "/r"\n[ros2]\n'
                    'node_name = "n"\n')
    cfg = load_config(path)
    for name in ("zenoh", "ros2"):
        with pytest.warns(DeprecationWarning, match=rf"ChassisConfig\.{name} moved to "
                          rf"ChassisConfig\.front_ends\['{name}'\]; the old name goes in "
                          "the next release"):
            assert getattr(cfg, name) is cfg.front_ends[name]
    with pytest.warns(DeprecationWarning, match="ChassisConfig.foxglove moved"):
        assert cfg.foxglove is None  # type: ignore[attr-defined]
    with pytest.raises(AttributeError):
        cfg.nothing  # type: ignore[attr-defined]  # noqa: B018


def test_a_config_made_with_a_table_by_its_old_name_warns_and_reads_it() -> None:
    from dataclasses import replace

    from omnican.config import default_config

    with pytest.warns(DeprecationWarning, match="ChassisConfig.ros2 moved"):
        cfg = replace(default_config(), ros2={"joint_names": ["a", "b", "c"]})
    assert cfg.front_ends["ros2"]["joint_names"] == ("a", "b", "c")
    with pytest.raises(TypeError, match="unexpected keyword argument 'rosx'"):
        replace(default_config(), rosx={})


@pytest.mark.parametrize("name", ["ZenohTable", "ZENOH_MODES", "ZENOH_RATES",
                                  "ZENOH_SECURITY"])
def test_a_name_of_the_zenoh_table_moved_from_the_config_warns(name: str) -> None:
    import omnican.config
    import omnican.zenoh.table

    with pytest.warns(DeprecationWarning, match=rf"omnican\.config\.{name} moved to "
                      rf"omnican\.zenoh\.table\.{name}; the old name goes in the next "
                      "release"):
        assert getattr(omnican.config, name) is getattr(omnican.zenoh.table, name)
    with pytest.raises(AttributeError):
        omnican.config.KEYS  # noqa: B018  # a table module's own name, never the config's


# -- names that mean one thing (issue 39 step 4) -----------------------------------------

def test_a_command_source_s_send_and_may_act_warn_and_answer_as_before() -> None:
    from omnican.chassis.actions import Action
    from omnican.chassis.arbiter import CommandArbiter, CommandSource
    from omnican.clock import SimClock
    from omnican.core.kinematics import Twist

    class Base:  # what a command source asks of a base, and no more
        def __init__(self) -> None:
            self.clock = SimClock()
            self.twists: list[Twist] = []

        def set_twist(self, twist: Twist) -> None:
            self.twists.append(twist)

    base, arbiter = Base(), CommandArbiter(0.5)
    keys = CommandSource(base, arbiter, "keys")  # type: ignore[arg-type]
    other = CommandSource(base, arbiter, "other")  # type: ignore[arg-type]
    moved = r"CommandSource\.{}\(\) moved to CommandSource\.{}, which returns an Outcome; " \
            "the old name goes in the next release"
    with pytest.warns(DeprecationWarning, match=moved.format("send", r"drive\(\)")):
        assert keys.send(Twist(0.1, 0.0, 0.0)) is None
    with pytest.warns(DeprecationWarning, match=moved.format("send", r"drive\(\)")):
        assert other.send(Twist(0.2, 0.0, 0.0)) == "keys"
    assert base.twists == [Twist(0.1, 0.0, 0.0)]
    with pytest.warns(DeprecationWarning, match=moved.format(
            "may_act", r"may\(Action\.RECOVER\)")):
        assert other.may_act() == "keys" == other.may(Action.RECOVER).refused_by
    with pytest.warns(DeprecationWarning, match="may_act"):
        assert keys.may_act() is None


def test_a_displacement_is_no_twist_and_the_old_forms_warn_for_one_release() -> None:
    from omnican import Displacement, Pose2D, Twist

    step = Displacement(0.3, -0.1, 0.4)
    pose = Pose2D.exp(step)
    with pytest.warns(DeprecationWarning, match=r"Pose2D\.exp\(Twist\) moved to Pose2D\.exp"
                      r"\(Displacement\) \(a Twist is a velocity: Displacement\.of\(twist, "
                      r"dt_s\)\); the old form goes in the next release"):
        assert Pose2D.exp(Twist(0.3, -0.1, 0.4)) == pose
    assert Pose2D.exp(Displacement.of(Twist(0.15, -0.05, 0.2), 2.0)) == pose
    back = pose.log()
    assert not isinstance(back, Twist)
    for old, new in (("vx", "dx"), ("vy", "dy"), ("wz", "dtheta")):
        with pytest.warns(DeprecationWarning, match=rf"a displacement's {old} moved to "
                          rf"Displacement\.{new} \(a Twist is a velocity\); the old name "
                          "goes in the next release"):
            assert getattr(back, old) == getattr(back, new)


def test_a_wheel_s_sdo_writes_under_their_old_name_warn_and_are_the_same() -> None:
    from dataclasses import replace

    import omnican.config
    from omnican import WheelConfig, default_config
    from omnican.config import SdoWrite

    moved = r"{} moved to WheelConfig\.sdo_writes \(the \[\[wheel\.sdo\]\] writes are no " \
            r"settings\); the old name goes in the next release"
    writes = (SdoWrite("0x2000:00", 500),)
    wheel = replace(default_config().wheels[0], sdo_writes=writes)
    with pytest.warns(DeprecationWarning, match=moved.format(r"WheelConfig\.settings")):
        assert wheel.settings is wheel.sdo_writes is writes
    with pytest.warns(DeprecationWarning, match=moved.format(r"WheelConfig\(settings=\)")):
        again = replace(default_config().wheels[0], settings=writes)
    assert again == wheel
    with pytest.warns(DeprecationWarning, match=moved.format(r"WheelConfig\(settings=\)")):
        made = WheelConfig(1, 0, wheel.eds, 1.0, 1.0, settings=writes)
    assert made.sdo_writes == writes
    with pytest.raises(TypeError, match="unexpected keyword argument 'setings'"):
        WheelConfig(1, 0, wheel.eds, 1.0, 1.0, setings=writes)  # type: ignore[call-arg]
    with pytest.warns(DeprecationWarning, match=r"omnican\.config\.VendorSetting moved to "
                      r"omnican\.config\.SdoWrite; the old name goes in the next release"):
        assert omnican.config.VendorSetting is SdoWrite
