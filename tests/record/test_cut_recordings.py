"""Recordings cut short (the recording process killed) or damaged (bytes overwritten):
what was written before the damage is read, and the readers say in one line how much
was not. Across processes: ``omnican drive --record`` killed with SIGKILL, then
``omnican plot`` on what it left."""

from __future__ import annotations

import contextlib
import io
import logging
import os
import re
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import can
import pytest

from omnican import default_config
from omnican.cli import main
from omnican.record import replay
from omnican.record.can_log import mcap_frames as read_mcap_frames
from tests.support.helpers import wait_for

ROOT = Path(__file__).resolve().parents[2]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SIZE = r"\d+(?:\.\d)? (?:bytes?|KB|MB)"
# The one line a reader says about a damaged or cut-off recording.
CUT = re.compile(rf"(?P<path>\S+): read (?P<seconds>\d+\.\d) s of frames; (?:the rest "
                 rf"(?:\((?P<rest>{SIZE})\) )?is damaged or cut off|the file ends there, "
                 rf"cut off \(never closed\)|(?P<lines>\d+) damaged or cut-off lines? \((?P<bytes>{SIZE})\) "
                 r"left out)")


def run_main(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def key(msg: can.Message) -> tuple[float, int, bytes, bool]:
    return (round(msg.timestamp, 6), msg.arbitration_id, bytes(msg.data), msg.is_rx)


def cut_line(records: list[str]) -> re.Match[str]:
    assert len(records) == 1, records
    m = CUT.fullmatch(records[0])
    assert m is not None, records[0]
    return m


# ---------------------------------------------------------------- across processes


@pytest.mark.parametrize("suffix", [".mcap", ".log"])
def test_a_killed_run_leaves_a_recording_plot_reads(tmp_path: Path, suffix: str) -> None:
    """``kill -9`` while driving: the recording holds what was written up to about a
    second before, and ``omnican plot`` draws it, saying in one line what it could not
    read."""
    path = tmp_path / f"run{suffix}"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with (tmp_path / "stderr.txt").open("w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "omnican", "drive", "--sim", "--vx", "0.1",
                                 "--duration", "30", "--record", str(path)],
                                stdout=subprocess.DEVNULL, stderr=err, env=env)
        try:
            # A few seconds of frames (about 50-60 KB a second either way) reach the file
            # while the run goes on.
            wait_for(lambda: path.exists() and path.stat().st_size > 150_000, 30.0, 0.05)
            assert proc.poll() is None, (tmp_path / "stderr.txt").read_text()
        finally:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    png = tmp_path / "run.png"
    code, out, err_text = run_main(["plot", str(path), "-o", str(png)])
    assert code == 0, err_text
    assert "Traceback" not in err_text
    lines = [line for line in err_text.splitlines() if line.strip()]
    if suffix == ".mcap" or lines:  # a .log may end on a whole line: nothing lost to say
        assert len(lines) == 1, err_text
        m = CUT.search(lines[0])
        assert m is not None and m["path"] == str(path), lines[0]
        assert float(m["seconds"]) > 0.5
    assert out.startswith(f"wrote {png}: ")
    assert png.read_bytes()[:8] == PNG_MAGIC
    if suffix == ".log":  # no frame made of a line the kill cut short
        data = path.read_bytes()
        assert len(replay.read_frames(path)) == data.count(b"\n")
        assert data.endswith(b"\n") or lines
    rep = replay.load(path, default_config())
    assert rep.complete_syncs > 50
    assert rep.poses[-1][0] > 0.01  # the base drove forward in what was read


# ---------------------------------------------------------------- in-process damage


@dataclass
class Recorded:
    path: Path
    frames: list[can.Message]


@pytest.fixture(scope="module")
def mcap_run(tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    """A 4 s run in simulated time: several chunks (one a second of the messages' clock),
    each written as it closed."""
    path = tmp_path_factory.mktemp("cut") / "run.mcap"
    code, _, err = run_main(["drive", "--sim", "--fast", "--vx", "0.1", "--duration", "4",
                             "--record", str(path)])
    assert code == 0, err
    return Recorded(path, read_mcap_frames(path))


@pytest.fixture(scope="module")
def log_run(tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    path = tmp_path_factory.mktemp("cut") / "run.log"
    code, _, err = run_main(["drive", "--sim", "--fast", "--vx", "0.1", "--duration", "2",
                             "--record", str(path)])
    assert code == 0, err
    return Recorded(path, replay.read_frames(path))


def test_a_whole_recording_reads_without_a_word(mcap_run: Recorded, log_run: Recorded,
                                                caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="omnican")
    assert len(mcap_run.frames) > 1000 and len(log_run.frames) > 1000
    assert len(replay.read_frames(mcap_run.path)) == len(mcap_run.frames)
    assert len(replay.read_frames(log_run.path)) == len(log_run.frames)
    assert caplog.records == []


def chunks(path: Path) -> list[tuple[int, int, int]]:
    """(start, end, CAN frames in it) of each chunk of an MCAP file, read with mcap's own
    stream reader."""
    from mcap.records import Channel, Chunk
    from mcap.stream_reader import StreamReader, breakup_chunk

    out = []
    can_channels: set[int] = set()
    with path.open("rb") as f:
        start = f.tell()
        for record in StreamReader(f, emit_chunks=True).records:
            if isinstance(record, Chunk):
                inner = breakup_chunk(record)
                can_channels |= {r.id for r in inner if isinstance(r, Channel)
                                 and r.topic in ("/from_can_bus", "/to_can_bus")}
                frames = sum(1 for r in inner if getattr(r, "channel_id", None) in can_channels)
                out.append((start, f.tell(), frames))
            start = f.tell()
    return out


@pytest.mark.parametrize("which", ["first", "middle", "last"])
@pytest.mark.parametrize("where", [0.01, 0.5, 0.99])
def test_a_cut_mcap_reads_the_chunks_before_the_cut(mcap_run: Recorded, tmp_path: Path,
                                                    which: str, where: float,
                                                    caplog: pytest.LogCaptureFixture) -> None:
    """Cut inside a chunk (as a kill leaves the one being written): every chunk before it
    is read, exactly as written."""
    spans = chunks(mcap_run.path)
    assert len(spans) >= 3  # a chunk at least every second of the 4 s run
    k = {"first": 1, "middle": len(spans) // 2, "last": len(spans) - 1}[which]
    start, end, _ = spans[k]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(mcap_run.path.read_bytes()[:start + int((end - start) * where)])
    caplog.set_level(logging.WARNING, logger="omnican")
    frames = read_mcap_frames(cut)
    before = sum(n for _, _, n in spans[:k])
    assert [key(m) for m in frames] == [key(m) for m in mcap_run.frames[:before]]
    m = cut_line([r.getMessage() for r in caplog.records])
    assert m["path"] == str(cut) and m["rest"] is not None
    assert float(m["seconds"]) == pytest.approx(frames[-1].timestamp - frames[0].timestamp,
                                                abs=0.051)


def test_an_mcap_cut_after_its_last_chunk_loses_no_frame(mcap_run: Recorded, tmp_path: Path,
                                                         caplog: pytest.LogCaptureFixture) -> None:
    """The summary and footer lost (as a kill during the close leaves it): every frame."""
    data = mcap_run.path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:chunks(mcap_run.path)[-1][1]])
    caplog.set_level(logging.WARNING, logger="omnican")
    assert [key(m) for m in read_mcap_frames(cut)] == [key(m) for m in mcap_run.frames]
    cut_line([r.getMessage() for r in caplog.records])  # says it is cut all the same


@pytest.mark.parametrize("damage", [b"\xff" * 50, b"\x00" * 50, bytes(range(100, 150))])
def test_corrupt_bytes_in_an_mcap_stop_the_read_there(mcap_run: Recorded, tmp_path: Path,
                                                      damage: bytes,
                                                      caplog: pytest.LogCaptureFixture) -> None:
    """50 bytes overwritten in a chunk: the chunks before it are read, nothing after (and
    nothing made of the damaged bytes)."""
    spans = chunks(mcap_run.path)
    k = len(spans) // 2
    start, end, _ = spans[k]
    data = bytearray(mcap_run.path.read_bytes())
    at = (start + end) // 2
    data[at:at + len(damage)] = damage
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    caplog.set_level(logging.WARNING, logger="omnican")
    frames = replay.read_frames(bad)
    before = sum(n for _, _, n in spans[:k])
    assert [key(m) for m in frames] == [key(m) for m in mcap_run.frames[:before]]
    m = cut_line([r.getMessage() for r in caplog.records])
    assert m["rest"] is not None


def test_a_log_cut_mid_line(log_run: Recorded, tmp_path: Path,
                            caplog: pytest.LogCaptureFixture) -> None:
    data = log_run.path.read_bytes()
    end = data.index(b"\n", len(data) // 2)
    cut = tmp_path / "cut.log"
    cut.write_bytes(data[:end - 5])  # the line loses its last 5 characters
    caplog.set_level(logging.WARNING, logger="omnican")
    frames = replay.read_frames(cut)
    whole_lines = data[:end].count(b"\n")  # complete lines before the cut one
    assert [key(m) for m in frames] == [key(m) for m in log_run.frames[:whole_lines]]
    m = cut_line([r.getMessage() for r in caplog.records])
    assert m["lines"] == "1"


@pytest.mark.parametrize("damage", [b"\xff" * 50, b"x" * 50, b"\x00" * 50])
def test_corrupt_bytes_in_a_log_lose_only_their_lines(log_run: Recorded, tmp_path: Path,
                                                     damage: bytes,
                                                     caplog: pytest.LogCaptureFixture) -> None:
    original = log_run.path.read_bytes()
    # The damage starts inside a line's timestamp, so that line cannot parse (damage that
    # lands wholly inside a channel name leaves a valid line: nothing to lose there).
    at = original.index(b"\n", len(original) // 2) + 4
    data = bytearray(original)
    data[at:at + len(damage)] = damage
    bad = tmp_path / "bad.log"
    bad.write_bytes(bytes(data))
    # One damaged line: from the line the damage starts in to the first newline after it
    # (the newlines it overwrote joined the lines between).
    first = original.count(b"\n", 0, at)
    last = original.count(b"\n", 0, data.index(b"\n", at + len(damage)))
    lost = set(range(first, last + 1))
    caplog.set_level(logging.WARNING, logger="omnican")
    frames = replay.read_frames(bad)
    expected = [key(m) for i, m in enumerate(log_run.frames) if i not in lost]
    assert [key(m) for m in frames] == expected
    m = cut_line([r.getMessage() for r in caplog.records])
    assert m["lines"] == "1"


def test_plot_and_calibrate_fit_read_a_cut_recording(mcap_run: Recorded, log_run: Recorded,
                                                     tmp_path: Path) -> None:
    for run in (mcap_run, log_run):
        data = run.path.read_bytes()
        cut = tmp_path / f"cut{run.path.suffix}"
        cut.write_bytes(data[:int(len(data) * 0.8)] + b"\x00garbage")
        png = tmp_path / "cut.png"
        x, y, theta = replay.load(cut, default_config()).poses[-1]  # as if measured
        for argv in (["plot", str(cut), "-o", str(png)],
                     ["calibrate", "--fit", str(cut), f"--pose={x},{y},{theta}", "--json"]):
            code, _, err = run_main(argv)
            assert code == 0, err
            lines = [line for line in err.splitlines() if line.strip()]
            assert len(lines) == 1 and CUT.search(lines[0]), err
        assert png.read_bytes()[:8] == PNG_MAGIC


def test_nothing_readable_is_still_refused_in_one_line(mcap_run: Recorded,
                                                       tmp_path: Path) -> None:
    """A recording cut before its first frames (as a crash left them before): one line."""
    head = tmp_path / "head.mcap"
    head.write_bytes(mcap_run.path.read_bytes()[:2000])  # the header and the attachment
    code, _, err = run_main(["plot", str(head), "-o", str(tmp_path / "x.png")])
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"omnican: error: {head}: no CAN frames in the recording"), err
