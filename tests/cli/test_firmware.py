"""omnican firmware: a program image into the drives, or one line saying why not."""

from __future__ import annotations

import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from omnican import Chassis, load_config
from omnican.cli import main
from omnican.sim import SimulatedBase
from omnican.sim.program import FACTORY_IMAGE
from tests.support.helpers import one_error_line

IMAGE = bytes((i * 13 + 5) & 0xFF for i in range(30_000))
WHEELS = "".join(f"[[wheel]]\nnode_id = {n}\ngear_ratio = 16\nencoder_cpr = 4096\n"
                 "wheel_radius = 0.05\n\n" for n in (1, 2, 3))


def firmware(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """The download as a user runs it (the one place that says how it is invoked):
    (exit status, stdout, stderr)."""
    code = main(["firmware", *args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def image(tmp_path: Path) -> Path:
    path = tmp_path / "drive.bin"
    path.write_bytes(IMAGE)
    return path


@pytest.fixture
def robot(tmp_path: Path, channel: str) -> Path:
    toml = tmp_path / "robot.toml"
    toml.write_text(f'[bus]\ninterface = "virtual"\nchannel = "{channel}"\n\n'
                    f'[chassis]\nlayout = "b21"\nbase_radius = 0.19\n\n{WHEELS}')
    return toml


@pytest.fixture
def sim(robot: Path) -> Iterator[SimulatedBase]:
    with SimulatedBase.from_config(load_config(robot),
                                   drive_options={2: {"program": False}}) as s:
        yield s


def test_every_drive_of_the_simulated_base_gets_the_image(
        capsys: pytest.CaptureFixture[str], image: Path) -> None:
    code, out, err = firmware(capsys, "--sim", "--image", str(image))
    assert code == 0, err
    lines = out.splitlines()
    crc = f"0x{zlib.crc32(IMAGE):08X}"
    for n, line in zip((1, 2, 3), lines, strict=False):
        assert line.startswith(f"node {n}: program of 30000 bytes downloaded in ")
        assert line.endswith(f"verified (CRC-32 {crc}) and started; the drive says: program "
                             f"started; flash: program valid; identification {crc}")
    assert lines[3] == "3 of 3 drives run the image"
    assert err == ""


def test_one_wheel_only(capsys: pytest.CaptureFixture[str], image: Path) -> None:
    code, out, _ = firmware(capsys, "--sim", "--image", str(image), "--wheel", "2")
    assert code == 0
    assert len(out.splitlines()) == 1 and out.startswith("node 3: program of 30000 bytes")


@pytest.mark.parametrize(("content", "why"), [
    (None, "no such file"),
    (b"", "the file is empty"),
    ("big", "bytes, more than the 16 MiB any drive's flash holds: the wrong file?"),
])
def test_a_bad_image_is_a_usage_error(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                      content: Any, why: str) -> None:
    path = tmp_path / "image.bin"
    if content == "big":
        with path.open("wb") as fh:
            fh.truncate((16 << 20) + 1)  # sparse
    elif content is not None:
        path.write_bytes(content)
    code, out, err = firmware(capsys, "--sim", "--image", str(path))
    assert code == 2 and out == ""
    assert one_error_line(err).startswith(f"omnican: error: firmware image {path}: ")
    assert why in err


def test_a_wheel_the_config_lacks_is_a_usage_error(capsys: pytest.CaptureFixture[str],
                                                   image: Path) -> None:
    code, _, err = firmware(capsys, "--sim", "--image", str(image), "--wheel", "3")
    assert code == 2
    assert one_error_line(err) == "omnican: error: --wheel 3: the config has wheels 0-2"


def test_a_drive_without_program_download_is_named(
        capsys: pytest.CaptureFixture[str], image: Path, robot: Path,
        sim: SimulatedBase) -> None:
    code, out, _ = firmware(capsys, "--config", str(robot), "--image", str(image))
    assert code == 1
    lines = out.splitlines()
    assert lines[1] == ("node 2: no program download: it has no 1F50h program 1 (CiA 302-3 "
                        "program download): its firmware is loaded some other way")
    assert "and started" in lines[0] and "and started" in lines[2]
    assert lines[3] == "2 of 3 drives run the image"


def test_refused_while_the_base_drives_and_nothing_written(
        capsys: pytest.CaptureFixture[str], image: Path, robot: Path,
        sim: SimulatedBase) -> None:
    with Chassis.open(load_config(robot)):
        code, out, err = firmware(capsys, "--config", str(robot), "--image", str(image))
    assert code == 1 and out == ""
    # (The base in this process may log on stderr too, on a loaded machine.)
    errors = [line for line in err.splitlines() if line.startswith("omnican: error: ")]
    assert len(errors) == 1 and "Traceback" not in err
    line = errors[0]
    assert line.startswith("omnican: error: firmware refused: ")
    assert line.endswith("; stop it first; nothing was written")
    for drive in sim.drives:
        assert drive.program is None or (drive.program.begun == 0 and drive.program.running
                                         and drive.program.image == FACTORY_IMAGE)


def test_a_crc_mismatch_is_not_started(capsys: pytest.CaptureFixture[str], image: Path,
                                       robot: Path, sim: SimulatedBase) -> None:
    sim.drives[0].comm.readers[(0x1F56, 1)] = lambda: 0x12345678
    code, out, _ = firmware(capsys, "--config", str(robot), "--image", str(image),
                            "--node", "1")
    assert code == 1
    assert out == (f"node 1: CRC mismatch: the drive identifies its program as 0x12345678, "
                   f"the image's CRC-32 is 0x{zlib.crc32(IMAGE):08X}: not started; the drive "
                   "says: program stopped; flash: program valid; identification 0x12345678\n")


def test_a_lost_drive_is_named(capsys: pytest.CaptureFixture[str], image: Path, robot: Path,
                               sim: SimulatedBase) -> None:
    sim.drives[0].freeze()
    code, out, err = firmware(capsys, "--config", str(robot), "--image", str(image),
                              "--node", "1", "--sdo-timeout", "0.3")
    assert code == 1 and "Traceback" not in err
    assert out == ("node 1: does not answer; the drive says: no answer (its state is "
                   "unknown: it may hold an incomplete program)\n")


def test_the_commands_default_sdo_timeout_is_the_librarys() -> None:
    from omnican.cli import firmware as command
    from omnican.drive import program

    assert command.DEFAULT_SDO_TIMEOUT_S == program.DEFAULT_SDO_TIMEOUT_S
