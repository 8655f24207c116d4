"""``[[wheel]] serial``: the drive's serial number that ``omnican commission`` finds it by
(issue 38). One serial is one drive: two nodes cannot share it."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.config.parsing import parse_config
from omnican.errors import ConfigError


def config(serials: list[Any], nodes: tuple[int, ...] = (1, 2, 3)) -> dict[str, Any]:
    wheels = [{"node_id": n, "velocity_scale": -4772.44, "position_scale": 48000.0}
              for n in nodes]
    for wheel, serial in zip(wheels, serials, strict=True):
        if serial is not None:
            wheel["serial"] = serial
    return {"chassis": {"layout": "b21", "base_radius": 0.19}, "wheel": wheels}


@given(st.lists(st.integers(0, 0xFFFFFFFF), min_size=3, max_size=3, unique=True))
def test_serials_parse_as_given(serials: list[int]) -> None:
    cfg = parse_config(config(serials))
    assert [w.serial for w in cfg.wheels] == serials


def test_no_serial_is_none() -> None:
    assert [w.serial for w in parse_config(config([None, 7, None])).wheels] == [None, 7, None]


@pytest.mark.parametrize(("serials", "says"), [
    ([5, 6, 5], "wheel[2].serial: 5 is already wheel[0]'s (node 1): one drive cannot be two "
                "nodes"),
    ([-1, 6, 7], "wheel[0].serial"),
    ([0x1_0000_0000, 6, 7], "wheel[0].serial"),
    (["0x12", 6, 7], "wheel[0].serial"),
])
def test_bad_serials_are_one_line(serials: list[Any], says: str) -> None:
    with pytest.raises(ConfigError) as exc:
        parse_config(config(serials))
    assert says in str(exc.value) and "\n" not in str(exc.value)
