"""PDO plans for drives whose EDS marks needed objects not PDO-mappable (pure)."""

from __future__ import annotations

import functools
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import WHEEL_EDS
from omnican.plan.pdo import (
    MAPPING_POLICIES,
    SDO_TRANSFER_BITS,
    NodePlan,
    frame_bits,
    plan_node,
)
from omnican.protocol.object_map import AxisObjects, Entry, Obj, load_dictionary
from tests.support.helpers import VENDOR_EDS

NEEDED = (Obj.TARGET_VELOCITY, Obj.CONTROLWORD, Obj.POSITION_ACTUAL, Obj.STATUSWORD)


@functools.cache
def _dictionary(eds: Path) -> object:
    return load_dictionary(eds, 1)


def plan(eds: object = WHEEL_EDS, unmappable: frozenset[Obj] = frozenset(), mapping: str = "try",
         axes: tuple[int, ...] = (0,)) -> tuple[NodePlan, dict[Obj, list[Entry]]]:
    """Plan one node as layout.py does, with ``unmappable`` objects marked PDOMapping=0."""
    d = _dictionary(eds)  # type: ignore[arg-type]
    objs: dict[Obj, list[Entry]] = {o: [] for o in NEEDED}
    for axis in axes:
        a = AxisObjects(d, axis)
        for o in NEEDED:
            e = a[o]
            e = replace(e, pdo_mappable=False) if o in unmappable else e
            if e not in objs[o]:
                objs[o].append(e)
    p = plan_node(1, d, cyclic_rx=objs[Obj.TARGET_VELOCITY], event_rx=objs[Obj.CONTROLWORD],
                  cyclic_tx=objs[Obj.POSITION_ACTUAL], event_tx=objs[Obj.STATUSWORD],
                  mapping=mapping)
    return p, objs


def mapped(p: NodePlan) -> list[tuple[int, int]]:
    return [(e.index, e.subindex) for pdo in p.rpdos + p.tpdos for e in pdo.entries]


def test_unmappable_target_is_tried_by_default() -> None:
    p, objs = plan(unmappable=frozenset({Obj.TARGET_VELOCITY}))
    target = objs[Obj.TARGET_VELOCITY][0]
    assert p.find(target, tx=False) is not None
    assert p.tried == (target,) and p.sdo == ()
    assert any("not PDO-mappable in its EDS: mapped anyway" in line for line in p.describe())


def test_eds_policy_sends_the_unmappable_target_by_sdo() -> None:
    p, objs = plan(unmappable=frozenset({Obj.TARGET_VELOCITY}), mapping="eds")
    target = objs[Obj.TARGET_VELOCITY][0]
    assert p.find(target, tx=False) is None
    assert [(t.entry, t.write, t.cyclic) for t in p.sdo] == [(target, True, True)]
    assert p.tried == ()
    # RPDO1 (controlword, on change) stays; the cyclic RPDO is gone; TPDO2 every SYNC.
    assert p.cyclic_bits() == frame_bits(4) + SDO_TRANSFER_BITS
    assert ("SDO every cycle: Target velocity (0x60FF:00) written by expedited SDO "
            "(request + answer, 270 bits)") in p.describe()


def test_sdo_policy_moves_targets_and_positions() -> None:
    p, _ = plan(VENDOR_EDS / "zlac8015d.eds", mapping="sdo", axes=(0, 1))
    assert {(t.entry.index, t.entry.subindex, t.write) for t in p.sdo} == {
        (0x60FF, 1, True), (0x60FF, 2, True), (0x6064, 1, False), (0x6064, 2, False)}
    assert all(t.cyclic for t in p.sdo)
    assert (0x6040, 0) in mapped(p) and (0x6041, 0) in mapped(p)
    assert p.cyclic_bits() == 4 * SDO_TRANSFER_BITS  # nothing else every cycle


@given(unmappable=st.frozensets(st.sampled_from(NEEDED)), mapping=st.sampled_from(MAPPING_POLICIES),
       eds=st.sampled_from([WHEEL_EDS, VENDOR_EDS / "zlac8015d.eds",
                            VENDOR_EDS / "roboteq_v80_21.eds", VENDOR_EDS / "maxon_epos4.eds"]))
def test_every_needed_object_travels_exactly_once(unmappable: frozenset[Obj], mapping: str,
                                                   eds: object) -> None:
    axes = (0,) if eds in (WHEEL_EDS, VENDOR_EDS / "maxon_epos4.eds") else (0, 1)
    p, objs = plan(eds, unmappable, mapping, axes)
    on_pdo = mapped(p)
    by_sdo = [(t.entry.index, t.entry.subindex) for t in p.sdo]
    cyclic = {Obj.TARGET_VELOCITY, Obj.POSITION_ACTUAL}
    for o, entries in objs.items():
        for e in entries:
            key = (e.index, e.subindex)
            assert on_pdo.count(key) + by_sdo.count(key) == 1, (o, key)
            expect_sdo = (mapping == "sdo" and o in cyclic) or (
                mapping != "try" and o in unmappable)
            assert (key in by_sdo) == expect_sdo, (o, mapping)
            assert (e in p.tried) == (mapping == "try" and o in unmappable)
    for t in p.sdo:
        # Reads are polled every cycle; only the controlword is written on change.
        assert t.cyclic == (t.entry.obj is not Obj.CONTROLWORD)
        assert t.write == (t.entry.obj in (Obj.TARGET_VELOCITY, Obj.CONTROLWORD))
    pdo_bits = sum(frame_bits(x.data_bytes) for x in p.rpdos + p.tpdos if x.cyclic)
    assert p.cyclic_bits() == pdo_bits + SDO_TRANSFER_BITS * sum(t.cyclic for t in p.sdo)


def test_unknown_policy_is_refused() -> None:
    with pytest.raises(ValueError, match="mapping must be one of try, eds, sdo"):
        plan(mapping="maybe")
