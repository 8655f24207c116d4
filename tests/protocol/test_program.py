"""Program download's numbers (CiA 302-3): the flash status, read both ways, and the
verdict on a drive's answers after a download."""

from __future__ import annotations

import zlib

from hypothesis import given
from hypothesis import strategies as st

from omnican.protocol.program import (
    FLASH_ERRORS,
    FLASH_NO_VALID_PROGRAM,
    FLASH_OK,
    Verdict,
    control_name,
    flash_status,
    flash_status_value,
    image_crc,
    verdict,
)

errors = st.integers(min_value=0, max_value=0x7F)
images = st.binary(min_size=1, max_size=256)


@given(st.booleans(), errors)
def test_a_flash_status_reads_back_as_written(in_progress: bool, error: int) -> None:
    status = flash_status(flash_status_value(in_progress, error))
    assert (status.in_progress, status.error) == (in_progress, error)
    assert status.valid == (not in_progress and error == FLASH_OK)


@given(st.integers(min_value=0, max_value=0xFFFFFFFF))
def test_bit_0_is_in_progress_and_bits_1_to_7_the_error(raw: int) -> None:
    status = flash_status(raw)
    assert status.in_progress == bool(raw & 1)
    assert status.error == (raw >> 1) & 0x7F
    assert status.describe()  # every value has words
    if status.in_progress:
        assert not status.valid and status.holds_program and "incomplete" in status.describe()


def test_the_flash_status_in_words() -> None:
    assert flash_status(0).describe() == "program valid"
    assert flash_status(FLASH_NO_VALID_PROGRAM << 1).describe() == "no valid program"
    assert not flash_status(FLASH_NO_VALID_PROGRAM << 1).holds_program
    assert flash_status(3 << 1).describe() == FLASH_ERRORS[3]
    assert flash_status(100 << 1).describe() == "error code 100"
    assert control_name(1) == "started" and control_name(9) == "state 9"


@given(images)
def test_the_identification_is_the_images_crc_32(image: bytes) -> None:
    assert image_crc(image) == zlib.crc32(image)


@given(images, st.booleans(), errors, st.one_of(st.none(), st.integers(0, 0xFFFFFFFF)))
def test_only_a_valid_flash_naming_the_image_is_verified(
        image: bytes, in_progress: bool, error: int, ident: int | None) -> None:
    status = flash_status(flash_status_value(in_progress, error))
    judged = verdict(status, ident, image)
    assert (judged is Verdict.VERIFIED) == (status.valid and ident == image_crc(image))
    if in_progress:
        assert judged is Verdict.INCOMPLETE
    elif error != FLASH_OK:
        assert judged is Verdict.INVALID


@given(images, images)
def test_another_images_identification_is_a_mismatch(image: bytes, other: bytes) -> None:
    ident = image_crc(other)
    expected = Verdict.VERIFIED if ident == image_crc(image) else Verdict.MISMATCH
    assert verdict(flash_status(0), ident, image) is expected
