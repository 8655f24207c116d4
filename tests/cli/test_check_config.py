"""check-config's verdicts as a user reads them (issue 31 items 13-15): what every
command refuses, check-config refuses too; the first line of a file says whether it
failed; a drive that stops on its own watchdog is not warned about as one that never
stops."""

from __future__ import annotations

from pathlib import Path

import pytest

from omnican.cli import main
from tests.support.helpers import VENDOR_EDS, one_error_line

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "robot.toml"


def test_joint_names_that_do_not_match_the_wheels_are_refused_with_the_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "names.toml"
    bad.write_text(EXAMPLE.read_text() + '\n[ros2]\njoint_names = ["a", "b"]\n')
    assert main(["check-config", str(bad)]) == 2
    out, err = capsys.readouterr()
    assert "OK" not in out
    line = one_error_line(err)
    assert f"{bad}: ros2.joint_names: 2 names for 3 wheels" in line
    # and a command that reads the config refuses it the same way, naming the file
    assert main(["drive", "--sim", "--config", str(bad), "--vx", "0.1",
                 "--duration", "0.1"]) == 2
    assert f"{bad}: ros2.joint_names: 2 names for 3 wheels" in one_error_line(
        capsys.readouterr().err)


def test_the_first_line_says_a_bus_load_too_high_failed(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(EXAMPLE.read_text().replace("rate_hz = 100 ", "rate_hz = 5000 "))
    assert main(["check-config", str(bad)]) == 2
    out, err = capsys.readouterr()
    first = out.splitlines()[0]
    assert first.startswith(f"{bad}: FAILED: bus load ") and "above 80 %" in first, first
    assert "OK" not in first
    assert "bus load above 80 %" in one_error_line(err)
    good = tmp_path / "good.toml"
    good.write_text(EXAMPLE.read_text())
    assert main(["check-config", str(good)]) == 0
    assert capsys.readouterr().out.splitlines()[0] == f"{good}: OK"


def _zlac(tmp_path: Path, watchdog_ms: int | None, eds: Path = VENDOR_EDS / "zlac8015d.eds"
          ) -> Path:
    sdo = ("" if watchdog_ms is None else
           f'[[wheel.sdo]]\nobject = "0x2000:00"\nvalue = {watchdog_ms}\n')
    cfg = tmp_path / "zlac.toml"
    cfg.write_text(
        '[bus]\ninterface = "socketcan"\nchannel = "can0"\nbitrate = 1000000\n'
        '[chassis]\nlayout = "b21"\nbase_radius = 0.2\n'
        + "".join(f'[[wheel]]\nnode_id = {n}\naxis = {a}\neds = "{eds}"\n'
                  "velocity_scale = 100.0\nposition_scale = 1000.0\n" + sdo
                  for n, a in ((1, 0), (1, 1), (2, 0))))
    return cfg


def test_a_zlac_with_its_can_watchdog_set_is_not_warned_it_never_stops(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check-config", str(_zlac(tmp_path, 500))]) == 0
    out = capsys.readouterr().out
    assert "will not stop by itself" not in out and "warning: no heartbeat" not in out, out
    assert out.count("its CAN watchdog Offline Communication Parameter (0x2000:00) = 500 ms "
                     "stops it") == 2  # nodes 1 and 2
    assert main(["check-config", str(_zlac(tmp_path, 0))]) == 0
    assert "is 0 (off): this drive will not stop by itself" in capsys.readouterr().out
    assert main(["check-config", str(_zlac(tmp_path, None))]) == 0
    assert ("warning: no heartbeat consumer (1016h): this drive will not stop by itself"
            in capsys.readouterr().out)


def test_a_watchdog_is_known_by_the_drive_its_eds_names(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The ZLAC8015D's EDS as another vendor's (only the vendor-ID changed): its 2000h is
    nothing omnican knows of (the table is keyed by vendor and product,
    omnican.protocol.vendors), so the drive is warned about as one that never stops."""
    source = (VENDOR_EDS / "zlac8015d.eds").read_text()
    stranger = tmp_path / "stranger.eds"
    stranger.write_text(source.replace("VendorNumber=0x00000100", "VendorNumber=0x12345678")
                        .replace("DefaultValue=0x00000100", "DefaultValue=0x12345678"))
    assert main(["check-config", str(_zlac(tmp_path, 500, stranger))]) == 0
    out = capsys.readouterr().out
    assert "its CAN watchdog" not in out, out
    assert out.count("warning: no heartbeat consumer (1016h): this drive will not stop by "
                     "itself") == 2  # nodes 1 and 2
