"""An object whose values need so many bits (the controlword's and the statusword's go
up to bit 15) is refused in a type narrower than that, and any integer type at least as
wide passes: a drive may declare its statusword UNSIGNED32 (issue 36, item 13)."""

from __future__ import annotations

from canopen import objectdictionary as od
from canopen.objectdictionary import datatypes as dt
from hypothesis import given
from hypothesis import strategies as st

from omnican.protocol.eds_check import INTEGER_TYPES, TYPE_NAMES, variable_problem


def variable(data_type: int) -> od.ODVariable:
    var = od.ODVariable("Statusword", 0x6041, 0)
    var.data_type = data_type
    return var


@given(st.sampled_from(sorted(INTEGER_TYPES)), st.sampled_from([8, 16, 24, 32]))
def test_a_word_narrower_than_its_bits_is_refused_naming_both(data_type: int, need: int
                                                              ) -> None:
    width = od.ODVariable.STRUCT_TYPES[data_type].size * 8
    problem = variable_problem(variable(data_type), "Statusword", min_bits=need)
    if width >= need:
        assert problem is None
    else:
        assert problem == (f"0x6041:00 Statusword has DataType 0x{data_type:04X} "
                           f"{TYPE_NAMES[data_type]}; omnican needs an integer type of at "
                           f"least {need} bits")


@given(st.sampled_from([dt.REAL32, dt.VISIBLE_STRING, dt.DOMAIN, dt.BOOLEAN]))
def test_what_is_no_integer_is_refused_whatever_its_width(data_type: int) -> None:
    assert variable_problem(variable(data_type), "Statusword", min_bits=8) is not None
