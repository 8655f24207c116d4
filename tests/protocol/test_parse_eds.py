"""An EDS file parsed once (omnican.protocol.object_map.parse_eds), whatever the node
ids: each caller still gets a dictionary of its own, the same as canopen's own parse for
its node id, and a file changed on disk is read again."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest
from canopen import objectdictionary as od
from canopen.objectdictionary import eds as canopen_eds
from hypothesis import given, settings
from hypothesis import strategies as st

from omnican import WHEEL_EDS
from omnican.protocol import object_map
from omnican.protocol.object_map import parse_eds
from tests.support.helpers import VENDOR_EDS, lockstep_rig

EDS_FILES = [WHEEL_EDS, *sorted(VENDOR_EDS.glob("*.eds"))]


def _plain(value: Any, seen: dict[int, str], where: str = "od") -> Any:
    """``value`` as plain data to compare: objects by their attributes, each object
    once (a parent link names where the object was first met)."""
    if isinstance(value, (int, float, str, bytes, bool, type(None))):
        return value
    if id(value) in seen:
        return ("seen", seen[id(value)])
    seen[id(value)] = where
    if isinstance(value, dict):
        return {k: _plain(v, seen, f"{where}[{k!r}]") for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        items = sorted(value, key=repr) if isinstance(value, (set, frozenset)) else value
        return (type(value).__name__, [_plain(v, seen, f"{where}[{i}]")
                                       for i, v in enumerate(items)])
    return (type(value).__name__,
            {k: _plain(v, seen, f"{where}.{k}") for k, v in sorted(vars(value).items())})


def _same(a: od.ObjectDictionary, b: od.ObjectDictionary) -> bool:
    return bool(_plain(a, {}) == _plain(b, {}))


@pytest.fixture(autouse=True)
def _fresh_cache(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(object_map, "_PARSED", {}, raising=False)


@settings(max_examples=40, deadline=None)
@given(path=st.sampled_from(EDS_FILES), node_id=st.integers(1, 127),
       again=st.booleans())
def test_a_parse_is_canopens_parse(path: Path, node_id: int, again: bool) -> None:
    """The first parse and every later one (a copy) are canopen's import_od of the file
    for that node id, object by object, attribute by attribute ($NODEID resolved)."""
    if again:
        parse_eds(path, node_id)
    assert _same(parse_eds(path, node_id), od.import_od(str(path), node_id))


@settings(max_examples=40, deadline=None)
@given(path=st.sampled_from(EDS_FILES), first=st.one_of(st.none(), st.integers(1, 127)),
       node_id=st.one_of(st.none(), st.integers(1, 127)))
def test_a_parse_for_another_node_is_canopens_parse(path: Path, first: int | None,
                                                    node_id: int | None) -> None:
    """A file parsed for one node id (or none) and then asked for another: the copy is
    canopen's import_od of the file for the second node id ($NODEID values, the node id),
    object by object, attribute by attribute."""
    parse_eds(path, first)
    assert _same(parse_eds(path, node_id), od.import_od(str(path), node_id))


def test_a_value_relative_to_the_node_id_is_each_nodes_own(tmp_path: Path) -> None:
    """Default and parameter values given as $NODEID+..., one that does not convert, and
    a file without any: each node's copy has what canopen parses for it."""
    text = WHEEL_EDS.read_text()
    assert "$NODEID" in text
    path = tmp_path / "relative.eds"
    path.write_text(text.replace("ParameterName=Producer heartbeat time",
                                 "ParameterName=Producer heartbeat time\n"
                                 "ParameterValue=$NODEID+0x10", 1)
                    .replace("DefaultValue=$NODEID+0x00000180", "DefaultValue=$NODEID+0x0000018Q", 1))
    parse_eds(path, 5)
    for node_id in (1, 127, 5):
        fresh = od.import_od(str(path), node_id)
        heartbeat = fresh[0x1017]
        assert isinstance(heartbeat, od.ODVariable) and heartbeat.value == node_id + 0x10
        assert _same(parse_eds(path, node_id), fresh)


def test_nodes_of_one_file_do_not_share_a_change() -> None:
    """Two drives of one EDS file (or one node parsed twice) change their dictionaries
    without the other seeing it: a simulated drive adds objects where its EDS lacks them
    and the host's plan keeps its own."""
    first, second, other = parse_eds(WHEEL_EDS, 1), parse_eds(WHEEL_EDS, 1), \
        parse_eds(WHEEL_EDS, 2)
    assert first is not second
    target = first[0x60FF]
    assert isinstance(target, od.ODVariable)
    target.default = 1234
    first.add_object(od.ODVariable("added", 0x5FFF, 0))
    for d in (second, other, parse_eds(WHEEL_EDS, 1)):
        var = d[0x60FF]
        assert isinstance(var, od.ODVariable) and var.default != 1234
        assert 0x5FFF not in d
    # The COB-IDs given as $NODEID+... are the node's own.
    tpdo1 = [parse_eds(WHEEL_EDS, n)[0x1800][1].default for n in (1, 2)]
    assert tpdo1[1] - tpdo1[0] == 1


def test_a_file_changed_on_disk_is_parsed_again(tmp_path: Path) -> None:
    path = tmp_path / "drive.eds"
    text = WHEEL_EDS.read_text()
    path.write_text(text)
    name = parse_eds(path, 1).device_information.product_name
    assert name
    path.write_text(text.replace(f"ProductName={name}", "ProductName=changed on disk"))
    st_ = path.stat()  # a rewrite within the file system's time resolution: still seen
    os.utime(path, ns=(st_.st_atime_ns, st_.st_mtime_ns + 1))
    assert parse_eds(path, 1).device_information.product_name == "changed on disk"


def test_opening_a_simulated_base_parses_each_file_once(
        channel: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The simulator's drives, their wiring, and the host's node plans and nodes all read
    the demo base's one EDS (nodes 1, 2 and 3): it is parsed once, not once per use or
    per node."""
    parsed: list[tuple[str, int | None]] = []
    real = canopen_eds.import_eds

    def counted(source: Any, node_id: int | None) -> od.ObjectDictionary:
        parsed.append((Path(str(source)).name, node_id))
        return real(source, node_id)

    monkeypatch.setattr(canopen_eds, "import_eds", counted)
    with lockstep_rig(channel) as (clock, sim, base):
        clock.sleep(0.05)
        assert len(sim.drives) == 3 and all(w.online for w in base.wheels)
        assert sorted(d.node_id for d in sim.drives) == [1, 2, 3]
    assert len(parsed) == 1 and parsed[0][0] == WHEEL_EDS.name


@pytest.mark.parametrize("path", EDS_FILES, ids=lambda p: p.name)
@pytest.mark.parametrize("parsed_first", [False, True])
def test_eds_axes_is_the_axis_count_of_canopens_parse(path: Path, parsed_first: bool) -> None:
    """A drive's axis count from its file (what the simulator sizes a drive by): the
    count of canopen's own parse, whether the file was parsed before or not."""
    object_map._PARSED.clear()
    if parsed_first:
        parse_eds(path, 5)
    want = object_map.count_axes(od.import_od(str(path), 1))
    assert object_map.eds_axes(path) == want
    assert object_map.eds_axes(path) == want  # from what was kept
