"""Per-axis object resolution on the bundled and the vendor EDS files."""

from __future__ import annotations

import pytest

from omnican import WHEEL_EDS
from omnican.protocol.object_map import AxisObjects, Obj, axis_layout, count_axes, load_dictionary
from tests.support.helpers import VENDOR_EDS


def test_bundled_single_axis() -> None:
    d = load_dictionary(WHEEL_EDS)
    assert (count_axes(d), axis_layout(d)) == (1, "single")
    ax = AxisObjects(d, 0)
    assert ax[Obj.TARGET_VELOCITY].address == "0x60FF:00"
    assert ax[Obj.STATUSWORD].bits == 16 and not ax[Obj.STATUSWORD].shared
    assert ax.record(Obj.VL_ACCEL) == 0x6048


def test_roboteq_offsets() -> None:
    d = load_dictionary(VENDOR_EDS / "roboteq_v80_21.eds")
    # The v80 firmware EDS declares a third channel at +0x1000 (0x7040...).
    assert (count_axes(d), axis_layout(d)) == (3, "offset")
    ax1 = AxisObjects(d, 1)
    assert ax1[Obj.CONTROLWORD].index == 0x6840
    assert ax1[Obj.POSITION_ACTUAL].index == 0x6864
    assert ax1[Obj.TARGET_VELOCITY].index == 0x68FF
    assert ax1[Obj.VL_TARGET].index == 0x6842
    assert not ax1[Obj.CONTROLWORD].shared
    assert AxisObjects(d, 0)[Obj.CONTROLWORD].index == 0x6040


def test_zlac_subindexed_with_shared_controlword() -> None:
    d = load_dictionary(VENDOR_EDS / "zlac8015d.eds")
    assert (count_axes(d), axis_layout(d)) == (2, "subindex")
    left, right = AxisObjects(d, 0), AxisObjects(d, 1)
    assert right[Obj.POSITION_ACTUAL].address == "0x6064:02"
    assert left[Obj.TARGET_VELOCITY].address == "0x60FF:01"
    assert right[Obj.CONTROLWORD].address == "0x6040:00" and right[Obj.CONTROLWORD].shared
    assert left[Obj.CONTROLWORD].shared
    assert left[Obj.STATUSWORD].bits == 32  # declared UNSIGNED32
    # 606Ch is declared UNSIGNED32, but holds a signed velocity.
    vel = right[Obj.VELOCITY_ACTUAL]
    assert vel.signed and vel.decode(vel.encode(-1234)) == -1234
    assert Obj.SUPPORTED_MODES not in left and Obj.VL_TARGET not in left
    with pytest.raises(KeyError, match="no vl target"):
        left[Obj.VL_TARGET]


def test_entry_codec_saturates() -> None:
    d = load_dictionary(WHEEL_EDS)
    vl = AxisObjects(d)[Obj.VL_TARGET]
    assert vl.bits == 16 and vl.signed
    assert vl.decode(vl.encode(100000)) == 32767
    assert vl.decode(vl.encode(-100000)) == -32768
