"""CiA 301 numbers: the predefined connection set, NMT names, SDO abort texts, and
that no other module keeps its own copy of them."""

from __future__ import annotations

import re
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from omnican.protocol import cia301
from omnican.protocol.cia301 import (
    FUNCTION_CODES,
    NmtState,
    abort_text,
    canopen_name,
    nmt_state_name,
)

PACKAGE = Path(cia301.__file__).resolve().parent


def test_canopen_names() -> None:
    assert [canopen_name(i) for i in (0x000, 0x080, 0x081, 0x100, 0x185, 0x37F, 0x580,
                                      0x5FF, 0x67F, 0x70A, 0x7E5)] == [
        "NMT", "SYNC", "EMCY node 1", "TIME", "TPDO1 node 5", "RPDO2 node 127", "",
        "SDO response node 127", "SDO request node 127", "heartbeat node 10", ""]
    assert canopen_name(0x181, extended=True) == ""


@given(st.sampled_from(FUNCTION_CODES), st.integers(1, 127))
def test_every_node_frame_names_its_function_and_node(code: tuple[int, str],
                                                      node_id: int) -> None:
    base, name = code
    assert canopen_name(base + node_id) == f"{name} node {node_id}"


@given(st.integers(0, 0x7FF))
def test_a_name_is_given_exactly_to_the_predefined_ids(can_id: int) -> None:
    predefined = can_id in (0x000, 0x080, 0x100) or any(
        base < can_id <= base + 127 for base, _ in FUNCTION_CODES)
    assert bool(canopen_name(can_id)) == predefined


@given(st.integers(0, 255))
def test_nmt_state_names_ignore_the_toggle_bit(value: int) -> None:
    assert nmt_state_name(value) == nmt_state_name(value & 0x7F)
    if value & 0x7F in set(NmtState):
        assert nmt_state_name(value) == cia301.NMT_STATE_NAMES[value & 0x7F]
    else:
        assert nmt_state_name(value) == str(value & 0x7F)


def test_abort_texts() -> None:
    assert abort_text(0x05040000) == "0x05040000 SDO protocol timed out"
    assert abort_text(0x06020000) == "0x06020000 object does not exist in the object dictionary"
    assert abort_text(0x12345678) == "0x12345678 unknown abort code"


# Numbers that only cia301 may spell out: SDO abort codes, PDO parameter indices,
# heartbeat objects, and the COB-ID bases of heartbeats and EMCY.
_OWN = re.compile(r"0x0[5-8]0[0-9A-F]{5}\b|0x1[468A]00\b|0x101[4-8]\b|0x700\s*\+|0x80\s*\+",
                  re.IGNORECASE)


def test_cia301_is_the_one_home_of_its_numbers() -> None:
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "cia301.py":
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            code = line.split("#", 1)[0]
            if _OWN.search(code) and '"' not in code and "'" not in code:
                offenders.append(f"{path.relative_to(PACKAGE)}:{number}: {line.strip()}")
    assert offenders == []
