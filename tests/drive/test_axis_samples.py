"""omnican.drive.AxisIO as the loop's counter sample: its samples and its reseed (a
reboot) go through the one fold, omnican.core.wheel_odometry."""

from __future__ import annotations

from types import SimpleNamespace

from hypothesis import given
from hypothesis import strategies as st

from omnican.core.wheel_odometry import EncoderCounters, fold_counter
from omnican.drive import AxisIO
from omnican.protocol.object_map import Entry


@given(bits=st.sampled_from([16, 32]), start=st.integers(0, (1 << 32) - 1),
       raws=st.lists(st.integers(0, (1 << 32) - 1), max_size=40),
       reseed_at=st.integers(0, 40))
def test_the_loop_folds_counters_as_replay_does(bits: int, start: int, raws: list[int],
                                                 reseed_at: int) -> None:
    """The control loop's fold of an AxisIO's samples is fold_counter, a reboot's
    reseed included: live odometry and a replayed recording read counters alike."""
    position = Entry(obj=None, index=0x6064, subindex=0, bits=bits, signed=True,
                     declared_signed=True, shared=False, pdo_mappable=True, writable=False,
                     name="Position actual value")
    wheel = SimpleNamespace(position_scale=1000.0)
    axis = AxisIO(0, wheel, None, position, position, None)  # type: ignore[arg-type]
    counters = EncoderCounters([axis], [bits], [wheel.position_scale])
    counts, last = 0.0, None
    for k, raw in enumerate(r % (1 << bits) for r in [start, *raws]):
        if k == reseed_at:
            axis.reseed()
            last = None
        counts = fold_counter(counts, last, raw, bits)
        last = raw
        axis.raw, axis.epoch = raw, k
        assert counters.fold(k) == [counts / 1000.0]
