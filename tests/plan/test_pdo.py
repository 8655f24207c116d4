"""PDO plans for drives whose EDS marks needed objects not PDO-mappable (pure)."""

from __future__ import annotations

import functools
import re
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
         axes: tuple[int, ...] = (0,), every_cycle: bool = False,
         ) -> tuple[NodePlan, dict[Obj, list[Entry]]]:
    """Plan one node as layout.py does, with ``unmappable`` objects marked PDOMapping=0;
    ``every_cycle``: the controlwords written every cycle (chassis.cyclic_controlword)."""
    d = _dictionary(eds) if isinstance(eds, Path) else eds
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
                  mapping=mapping, event_rx_every_cycle=every_cycle)
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
    p, objs = plan(eds, unmappable, mapping, axes)  # controlwords on change
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


# ---------------------------------------------------------------- the controlword every cycle

EDS_FILES = [WHEEL_EDS, VENDOR_EDS / "zlac8015d.eds", VENDOR_EDS / "roboteq_v80_21.eds",
             VENDOR_EDS / "maxon_epos4.eds"]


def single_entry_eds(dest: Path, source: Path = WHEEL_EDS) -> Path:
    """A copy of ``source`` whose PDOs each take one mapping entry (16xxh, 1Axxh)."""
    out: list[str] = []
    keep, mapping = True, False
    for line in source.read_text().splitlines():
        text = line.strip()
        if text.startswith("["):
            m = re.fullmatch(r"\[(1[6A][0-9A-Fa-f]{2})(?:sub([0-9A-Fa-f]+))?\]", text)
            mapping = m is not None
            keep = not (m is not None and m.group(2) is not None and int(m.group(2), 16) >= 2)
        if keep:
            out.append("SubNumber=2" if mapping and text.startswith("SubNumber=") else line)
    dest.write_text("\n".join(out) + "\n")
    return dest


@given(unmappable=st.frozensets(st.sampled_from(NEEDED)), mapping=st.sampled_from(MAPPING_POLICIES),
       eds=st.sampled_from(EDS_FILES))
def test_every_controlword_goes_every_cycle_and_once(unmappable: frozenset[Obj], mapping: str,
                                                     eds: Path) -> None:
    """With the controlwords every cycle: each needed object still travels exactly once;
    every RPDO goes every SYNC (none on change), and so does every SDO transfer; a
    controlword goes by SDO only where the EDS moves it there, never for the "sdo"
    policy (the targets' and positions')."""
    axes = (0,) if eds in (WHEEL_EDS, VENDOR_EDS / "maxon_epos4.eds") else (0, 1)
    p, objs = plan(eds, unmappable, mapping, axes, every_cycle=True)
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
    assert all(r.cyclic for r in p.rpdos)
    assert all(t.cyclic for t in p.sdo)
    pdo_bits = sum(frame_bits(x.data_bytes) for x in p.rpdos + p.tpdos if x.cyclic)
    assert p.cyclic_bits() == pdo_bits + SDO_TRANSFER_BITS * len(p.sdo)


def _rpdo_layout(p: NodePlan) -> list[list[tuple[int, int]]]:
    return [[(e.index, e.subindex) for e in r.entries] for r in p.rpdos]


@pytest.mark.parametrize(("eds", "axes", "layout", "bits"), [
    # one axis: the controlword beside the target, one 6-byte frame (+20 bits a cycle)
    (WHEEL_EDS, (0,), [[(0x60FF, 0), (0x6040, 0)]], frame_bits(6)),
    (VENDOR_EDS / "maxon_epos4.eds", (0,), [[(0x60FF, 0), (0x6040, 0)]], frame_bits(6)),
    # ZLAC8015D: two sub-indexed targets fill a frame; the one controlword gets its own
    (VENDOR_EDS / "zlac8015d.eds", (0, 1), [[(0x60FF, 1), (0x60FF, 2)], [(0x6040, 0)]],
     frame_bits(8) + frame_bits(2)),
    # Roboteq: axes at +0x800, a controlword each, both on the second frame
    (VENDOR_EDS / "roboteq_v80_21.eds", (0, 1), [[(0x60FF, 0), (0x68FF, 0)],
                                                 [(0x6040, 0), (0x6840, 0)]],
     frame_bits(8) + frame_bits(4)),
])
def test_the_controlword_rides_beside_the_targets(eds: Path, axes: tuple[int, ...],
                                                  layout: list[list[tuple[int, int]]],
                                                  bits: int) -> None:
    p, _ = plan(eds, axes=axes, every_cycle=True)
    assert _rpdo_layout(p) == layout
    assert all(r.cyclic and r.trans_type == 1 for r in p.rpdos)
    rx_bits = sum(frame_bits(r.data_bytes) for r in p.rpdos)
    assert rx_bits == bits
    # On change instead: the controlwords' RPDO costs nothing a cycle.
    q, _ = plan(eds, axes=axes)
    assert sum(frame_bits(r.data_bytes) for r in q.rpdos if r.cyclic) < rx_bits
    assert any(not r.cyclic for r in q.rpdos)


def test_a_single_entry_drive_gets_a_second_cyclic_rpdo(tmp_path: Path) -> None:
    eds = single_entry_eds(tmp_path / "single.eds")
    p, _ = plan(load_dictionary(eds, 1), every_cycle=True)
    assert _rpdo_layout(p) == [[(0x60FF, 0)], [(0x6040, 0)]]
    assert all(r.cyclic for r in p.rpdos)
    assert sum(frame_bits(r.data_bytes) for r in p.rpdos) == frame_bits(4) + frame_bits(2)
