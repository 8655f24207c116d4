"""Damaged recordings in every format omnican records (issue 36, item 13): each says in
one line what it could not read and plots the rest, as .log, .csv and .mcap did; a time
that is no number is damage too (plot ended in matplotlib's "Axis limits cannot be NaN
or Inf"); python-can's own "TRCReader: Failed to parse message" is not a user's line."""

from __future__ import annotations

import contextlib
import io
import math
import re
from pathlib import Path

import pytest

from omnican.cli import main
from omnican.record.can_log import cut_note, size_text
from omnican.record.read import read_recording
from tests.record.test_cut_recordings import CUT, PNG_MAGIC

FORMATS = (".log", ".asc", ".blf", ".csv", ".trc")


def run_main(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One run in simulated time, recorded in each format."""
    out = {}
    folder = tmp_path_factory.mktemp("formats")
    for suffix in FORMATS:
        path = folder / f"run{suffix}"
        code, _, err = run_main(["drive", "--sim", "--fast", "--vx", "0.1", "--duration", "1.5",
                                 "--record", str(path)])
        assert code == 0, err
        out[suffix] = path
    return out


def plot(path: Path, tmp_path: Path) -> tuple[int, list[str]]:
    """omnican plot's exit status and the lines it wrote on stderr (a PNG is checked)."""
    png = tmp_path / f"{path.name}.png"
    code, _, err = run_main(["plot", str(path), "-o", str(png)])
    assert "Traceback" not in err
    if code == 0:
        assert png.read_bytes()[:8] == PNG_MAGIC
    return code, [line for line in err.splitlines() if line.strip()]


@pytest.mark.parametrize("suffix", FORMATS)
def test_a_whole_recording_plots_without_a_word(runs: dict[str, Path], suffix: str,
                                                tmp_path: Path) -> None:
    assert plot(runs[suffix], tmp_path) == (0, [])


@pytest.mark.parametrize("suffix", FORMATS)
@pytest.mark.parametrize("share", [0.5, 0.77])
def test_a_recording_cut_short_says_so_in_one_line(runs: dict[str, Path], suffix: str,
                                                   share: float, tmp_path: Path) -> None:
    """Cut anywhere (mid-line, mid-record), each format plots what it has and says what
    it could not read: .blf and .asc said nothing, .trc python-can's words. (A text log
    cut exactly at a line's end shows nothing, but for an .asc's missing end: below.)"""
    data = runs[suffix].read_bytes()
    at = int(len(data) * share)
    if data[at - 1:at] == b"\n":
        at += 3  # mid-line
    cut = tmp_path / f"cut{suffix}"
    cut.write_bytes(data[:at])
    code, lines = plot(cut, tmp_path)
    assert code == 0
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"omnican: WARNING: {cut}: read ")
    assert CUT.fullmatch(lines[0].removeprefix("omnican: WARNING: ")), lines[0]
    assert "TRCReader" not in lines[0]


def test_an_asc_cut_at_a_line_end_was_never_closed(runs: dict[str, Path], tmp_path: Path
                                                   ) -> None:
    """A cut that falls between lines leaves no broken line; what shows it is the missing
    'end triggerblock' a closed .asc ends with."""
    text = runs[".asc"].read_text()
    assert text.rstrip().endswith("End TriggerBlock")
    lines = text.splitlines(keepends=True)
    cut = tmp_path / "cut.asc"
    cut.write_text("".join(lines[: len(lines) * 2 // 3]))
    code, said = plot(cut, tmp_path)
    assert code == 0
    assert said == [f"omnican: WARNING: {cut}: read {_seconds(cut)} s of frames; the file "
                    "ends there, cut off (never closed)"]


def test_a_blf_never_closed_says_so(runs: dict[str, Path], tmp_path: Path) -> None:
    """A writer killed before it closed the file leaves the header's size at the
    header's own (python-can writes the size when it closes)."""
    data = bytearray(runs[".blf"].read_bytes())
    assert int.from_bytes(data[16:24], "little") == len(data)  # closed: its size
    data[16:24] = (144).to_bytes(8, "little")
    cut = tmp_path / "killed.blf"
    cut.write_bytes(bytes(data))
    code, said = plot(cut, tmp_path)
    assert code == 0
    assert said == [f"omnican: WARNING: {cut}: read {_seconds(cut)} s of frames; the file "
                    "ends there, cut off (never closed)"]


def _seconds(path: Path) -> str:
    frames, _ = read_recording(path)
    stamps = [f.timestamp for f in frames]
    return f"{max(stamps) - min(stamps):.1f}"


def test_a_trc_line_python_can_cannot_parse_is_counted(runs: dict[str, Path], tmp_path: Path
                                                       ) -> None:
    lines = runs[".trc"].read_text().splitlines(keepends=True)
    body = [k for k, line in enumerate(lines) if not line.startswith(";")]
    for k in body[100:103]:
        lines[k] = lines[k].split()[0] + "\n"  # a message number and nothing more
    bad = tmp_path / "bad.trc"
    bad.write_text("".join(lines))
    code, said = plot(bad, tmp_path)
    assert code == 0
    assert len(said) == 1 and "TRCReader" not in said[0], said
    m = CUT.fullmatch(said[0].removeprefix("omnican: WARNING: "))
    assert m is not None and m["lines"] == "3", said


# ---------------------------------------------------------------- times that are no number


def _nan_log(source: Path, target: Path, every: int) -> int:
    """``source`` with the time of every ``every``-th line made ``nan``; how many."""
    lines = source.read_text().splitlines()
    made = 0
    for k, line in enumerate(lines):
        if k % every == 0:
            lines[k] = "(nan)" + line.split(")", 1)[1]
            made += 1
    target.write_text("\n".join(lines) + "\n")
    return made


def test_a_log_whose_times_are_nan_is_refused_in_one_line(runs: dict[str, Path],
                                                          tmp_path: Path) -> None:
    nan = tmp_path / "nan.log"
    made = _nan_log(runs[".log"], nan, 1)
    code, said = plot(nan, tmp_path)
    assert code == 2
    assert said == [f"omnican: error: {nan}: no CAN frame with a valid time ({made} lines "
                    "whose time is no number, such as '(nan)')"]


def test_a_few_nan_times_are_left_out_and_counted(runs: dict[str, Path], tmp_path: Path
                                                  ) -> None:
    nan = tmp_path / "some.log"
    made = _nan_log(runs[".log"], nan, 40)
    frames, note = read_recording(nan)
    assert all(math.isfinite(f.timestamp) for f in frames)
    assert note is not None and re.fullmatch(rf"read \d+\.\d s of frames; {made} damaged or "
                                             r"cut-off lines \(.+\) left out", note), note
    code, said = plot(nan, tmp_path)
    assert code == 0 and len(said) == 1 and said[0].endswith(note)


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
def test_a_csv_row_whose_time_is_no_number_is_left_out(runs: dict[str, Path], bad: str,
                                                       tmp_path: Path) -> None:
    lines = runs[".csv"].read_text().splitlines()
    for k in (5, 50, 500):
        lines[k] = bad + lines[k][lines[k].index(","):]
    damaged = tmp_path / "bad.csv"
    damaged.write_text("\n".join(lines) + "\n")
    frames, note = read_recording(damaged)
    assert all(math.isfinite(f.timestamp) for f in frames)
    assert note is not None and note.endswith("; 3 frames with no valid time left out"), note
    code, said = plot(damaged, tmp_path)
    assert code == 0 and len(said) == 1


def test_one_byte_is_one_byte() -> None:
    assert [size_text(n) for n in (0, 1, 2, 1023, 1024)] == [
        "0 bytes", "1 byte", "2 bytes", "1023 bytes", "1 KB"]
    assert cut_note([], 1, 1) == "read 0.0 s of frames; 1 damaged or cut-off line (1 byte) left out"
