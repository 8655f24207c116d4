"""The CAN controller's state from SocketCAN error frames (omnican.protocol.can_state), pure."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from omnican.protocol import can_state as cs


def frame(can_id: int, *data: int) -> bytes:
    return bytes(data).ljust(8, b"\0")


def test_warning_passive_bus_off_and_restart() -> None:
    c = cs.CanController()
    assert c.state.state == cs.ERROR_ACTIVE and c.state.error_frames == 0
    c.on_error_frame(cs.ERR_CRTL | cs.ERR_CNT, frame(0, 0, cs.CRTL_TX_WARNING, 0, 0, 0, 0, 97, 3))
    assert c.state.state == cs.ERROR_WARNING
    assert (c.state.tx_errors, c.state.rx_errors) == (97, 3)
    assert c.state.describe() == "error-warning (tx 97, rx 3)"
    c.on_error_frame(cs.ERR_CRTL, frame(0, 0, cs.CRTL_RX_PASSIVE, 0, 0, 0, 0, 97, 130))
    assert c.state.state == cs.ERROR_PASSIVE and c.state.rx_errors == 130
    c.on_error_frame(cs.ERR_BUSOFF, b"")
    assert c.state.bus_off and c.state.bus_offs == 1
    assert c.state.last_error == "bus-off"
    c.on_error_frame(cs.ERR_CRTL, frame(0, 0, cs.CRTL_TX_WARNING))  # bus-off holds
    assert c.state.bus_off
    c.on_error_frame(cs.ERR_RESTARTED, b"")
    assert c.state.state == cs.ERROR_ACTIVE and c.state.restarts == 1
    assert c.state.error_frames == 5


def test_the_other_errors_are_named() -> None:
    assert cs.describe_error(cs.ERR_ACK, b"") == "no acknowledgement (no other node on the bus?)"
    assert cs.describe_error(cs.ERR_PROT, frame(0, 0, 0, 0x04)) == \
        "protocol error: bit stuffing error"
    assert "receive overflow" in cs.describe_error(cs.ERR_CRTL, frame(0, 0, cs.CRTL_RX_OVERFLOW))
    assert cs.describe_error(0, b"") == "error frame 0x000"


_FRAMES = st.tuples(st.sampled_from([cs.ERR_CRTL, cs.ERR_BUSOFF, cs.ERR_RESTARTED, cs.ERR_ACK,
                                     cs.ERR_PROT, cs.ERR_CRTL | cs.ERR_CNT, cs.ERR_LOSTARB]),
                    st.binary(min_size=0, max_size=8))


@given(frames=st.lists(_FRAMES, max_size=50))
def test_bus_off_ends_only_with_a_restart(frames: list[tuple[int, bytes]]) -> None:
    """Whatever comes: the state is one of the four; a bus-off controller leaves bus-off
    only on a restart (or its saying it is error-active again); every frame is counted."""
    state = cs.ControllerState()
    for can_id, data in frames:
        after = cs.next_state(state, can_id, data)
        assert after.state in cs.STATES
        assert after.error_frames == state.error_frames + 1
        if state.bus_off and not after.bus_off:
            assert can_id & cs.ERR_RESTARTED or (can_id & cs.ERR_CRTL and len(data) > 1 and
                                                  data[1] & cs.CRTL_ACTIVE)
        if can_id & cs.ERR_BUSOFF:
            assert after.bus_off
        state = after
