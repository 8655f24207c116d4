"""The compiled wire layout of a PDO: packing is what each object's own encoding gives,
unpacking reads it back, and the loop's one-call forms agree with the plain ones."""

from __future__ import annotations

from hypothesis import assume, given
from hypothesis import strategies as st

from omnican.plan.codec import PdoCodec
from omnican.plan.pdo import PlannedPdo
from omnican.protocol.object_map import Entry


def entry(bits: int, signed: bool, subindex: int) -> Entry:
    return Entry(obj=None, index=0x2000, subindex=subindex, bits=bits, signed=signed,
                 declared_signed=signed, shared=False, pdo_mappable=True, writable=True,
                 name=f"field {subindex}")


layouts = st.lists(st.tuples(st.sampled_from([8, 16, 24, 32]), st.booleans()),
                   min_size=1, max_size=4).filter(lambda fs: sum(b for b, _ in fs) <= 64)


def codec_of(fields: list[tuple[int, bool]]) -> PdoCodec:
    entries = tuple(entry(bits, signed, i + 1) for i, (bits, signed) in enumerate(fields))
    return PdoCodec(PlannedPdo(number=1, cob_id=0x201, trans_type=1, entries=entries))


@given(fields=layouts, data=st.data())
def test_pack_is_each_objects_encoding_and_unpack_reads_it_back(
        fields: list[tuple[int, bool]], data: st.DataObject) -> None:
    codec = codec_of(fields)
    values = data.draw(st.lists(st.integers(-(1 << 40), 1 << 40), min_size=len(fields),
                                max_size=len(fields)))
    packed = codec.pack(values)
    assert packed == b"".join(f.entry.encode(v) for f, v in zip(codec.fields, values,
                                                                     strict=True))
    assert len(packed) == codec.length
    assert codec.unpack(packed) == tuple(max(f.lo, min(f.hi, v))
                                         for f, v in zip(codec.fields, values, strict=True))
    assert codec.unpack(packed[:-1]) is None  # a short frame is not this PDO


@given(fields=layouts, data=st.data())
def test_the_loops_packer_is_pack_for_values_in_range(
        fields: list[tuple[int, bool]], data: st.DataObject) -> None:
    codec = codec_of(fields)
    values = [data.draw(st.integers(lo, hi)) for lo, hi in codec.ranges]
    assert codec.packer()(*values) == codec.pack(values)


@given(fields=layouts, data=st.data())
def test_an_rpdos_one_call_fill_is_pack_of_its_values(
        fields: list[tuple[int, bool]], data: st.DataObject) -> None:
    """The loop refills each RPDO with ``fill(speeds)``: the same bytes as packing the
    field values, targets beyond an object's range saturated."""
    from types import SimpleNamespace

    from omnican.drive.cyclic import _RpdoIO
    from omnican.io.bus import prepared_message
    from omnican.plan.pdo import frame_bits

    codec = codec_of(fields)
    io = _RpdoIO(codec.pdo, codec, prepared_message(0x201, bytes(codec.length)),
                 frame_bits(codec.length))
    for _ in fields:
        role = data.draw(st.sampled_from(["target", "controlword", "other"]))
        if role == "target":
            axis = SimpleNamespace(wheel_index=data.draw(st.integers(0, 2)))
            io.sources.append((axis, data.draw(st.floats(-1e6, 1e6)), None))  # type: ignore[arg-type]
        elif role == "controlword":
            stage = SimpleNamespace(cw=data.draw(st.integers(0, 0xFFFF)))
            io.sources.append((None, 0.0, stage))  # type: ignore[arg-type]
        else:
            io.sources.append((None, 0.0, None))
    io.seal()
    speeds = data.draw(st.lists(st.floats(-1e4, 1e4), min_size=3, max_size=3))
    for s in (speeds, []):
        io.fill(s)
        assert bytes(io.msg.data) == codec.pack(io.values(s))
    # The same list again (the loop's targets held), a controlword changed meanwhile.
    io.fill(speeds)
    for _, _, stage in io.sources:
        if stage is not None:
            stage.cw ^= 0x0F
    io.fill(speeds)
    assert bytes(io.msg.data) == codec.pack(io.values(speeds))


@given(targets=st.integers(1, 2), controlwords=st.integers(0, 2),
       target_bits=st.sampled_from([16, 32]), data=st.data())
def test_the_plans_own_layout_fills_as_packing_its_values(
        targets: int, controlwords: int, target_bits: int, data: st.DataObject) -> None:
    """The plan's cyclic RPDO (targets, then the controlwords sent every cycle) is filled
    on its own short path: the same bytes as packing the field values, the targets
    saturated, each controlword as its stage holds it, a changed one sent."""
    from types import SimpleNamespace

    from omnican.drive.cyclic import _RpdoIO
    from omnican.io.bus import prepared_message
    from omnican.plan.pdo import frame_bits

    fields = [(target_bits, True)] * targets + [(16, False)] * controlwords
    assume(sum(bits for bits, _ in fields) <= 64)
    codec = codec_of(fields)
    io = _RpdoIO(codec.pdo, codec, prepared_message(0x201, bytes(codec.length)),
                 frame_bits(codec.length))
    stages = []
    for k in range(targets):
        axis = SimpleNamespace(wheel_index=k)
        io.sources.append((axis, data.draw(st.floats(-1e6, 1e6)), None))  # type: ignore[arg-type]
    for _ in range(controlwords):
        stages.append(SimpleNamespace(cw=data.draw(st.integers(0, 0xFFFF))))
        io.sources.append((None, 0.0, stages[-1]))  # type: ignore[arg-type]
    io.seal()
    assert io._targets is not None  # the short path
    speeds = data.draw(st.lists(st.floats(-1e4, 1e4), min_size=2, max_size=2))
    io.fill(speeds)
    assert bytes(io.msg.data) == codec.pack(io.values(speeds))
    for stage in stages:
        stage.cw = data.draw(st.integers(0, 0xFFFF))
    io.fill(speeds)  # the same targets, new controlwords
    assert bytes(io.msg.data) == codec.pack(io.values(speeds))
