"""``omnican monitor`` through its entry point, on the virtual bus."""

from __future__ import annotations

import re
import sys
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from omnican.cli import main, monitor
from tests.support.helpers import one_error_line

ROW = re.compile(r"^(0x[0-9A-F]{3,8})\s+(.+?)\s+(\d+)\s+(\d+\.\d)(?:  (.*))?$")


def tables(out: str) -> list[tuple[str, dict[str, tuple[str, int, float, str]], list[str]]]:
    """The plain-text tables of the output: (title, rows by id, bus lines)."""
    found = []
    for block in out.split("omnican monitor (")[1:]:
        lines = block.strip().splitlines()
        rows: dict[str, tuple[str, int, float, str]] = {}
        for line in lines[2:]:
            m = ROW.match(line)
            if m:
                rows[m.group(1)] = (m.group(2), int(m.group(3)), float(m.group(4)),
                                    m.group(5) or "")
        bus = [line for line in lines if line.startswith(("bus load:", "total:"))]
        found.append((lines[0], rows, bus))
    return found


def run_ok(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return captured.out


def one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    return one_error_line(capsys.readouterr().err)


# ------------------------------------------------------------------ --sim


def test_sim_shows_decoded_pdos_rates_and_bus_load(capsys: pytest.CaptureFixture[str]) -> None:
    out = run_ok(["monitor", "--sim", "--duration", "1.5", "--interval", "0.5"], capsys)
    found = tables(out)
    assert len(found) >= 2
    assert all("live" in title for title, _, _ in found[:-1])
    title, rows, bus = found[-1]
    assert title.startswith("summary, ") and "simulated base" in title
    name, count, rate, signals = rows["0x080"]
    assert (name, signals) == ("SYNC", "")
    assert 50 <= rate <= 150  # the 100 Hz control loop's SYNC
    assert count > 50
    for node in (1, 2, 3):
        name, count, rate, signals = rows[f"0x{0x200 + node:03X}"]
        assert name == f"RPDO1_node{node}"
        assert re.fullmatch(r"TargetVelocity=-?\d+ inc/s  Controlword=0x[0-9A-F]{4} .+", signals)
        assert 50 <= rate <= 150
        name, count, rate, signals = rows[f"0x{0x280 + node:03X}"]
        assert name == f"TPDO2_node{node}"
        assert re.fullmatch(r"PositionActual=-?\d+ inc", signals)
        assert 50 <= rate <= 150
        name, _, _, signals = rows[f"0x{0x180 + node:03X}"]
        assert name == f"TPDO1_node{node}"
        assert re.match(r"Statusword=0x[0-9A-F]{4} [A-Z ]+  ModeDisplay=profile velocity  "
                        r"ErrorCode=", signals)
        assert rows[f"0x{0x200 + node:03X}"][0] == f"RPDO1_node{node}"
        assert rows[f"0x{0x700 + node:03X}"][0] == f"Heartbeat_node{node}"
        assert rows[f"0x{0x700 + node:03X}"][3].startswith("NmtState=")
        # ids the DBC lacks: their CANopen meaning and raw hex
        name, _, _, signals = rows[f"0x{0x600 + node:03X}"]
        assert name == f"SDO request node {node}"
        assert re.fullmatch(r"([0-9A-F]{2} ){7}[0-9A-F]{2}", signals)
    assert rows["0x77F"][0] == "Heartbeat_host"
    assert rows["0x77F"][3] == "NmtState=operational"
    assert rows["0x000"][0] == "NMT"
    # the demo moves the base: the wheels were commanded and turned
    assert any(re.search(r"TargetVelocity=-?[1-9]", r[3]) for _, rs, _ in found for r in rs.values())
    assert any("OPERATION ENABLED" in r[3] for _, rs, _ in found for r in rs.values())
    assert any(rows[f"0x{0x280 + n:03X}"][3] != "PositionActual=0 inc" for n in (1, 2, 3))
    # the simulated bus stands for the demo base's: 500 kbit/s (no config gives one)
    assert re.fullmatch(r"bus load: \d+\.\d kbit/s worst case over the last 1\.0 s \(\d+\.\d% "
                        r"of 500 kbit/s\)", bus[0])
    assert float(bus[0].split()[2]) > 0
    assert re.fullmatch(r"total: \d+ frames in \d+\.\d s, mean \d+\.\d kbit/s", bus[1])


def test_sim_bus_load_in_percent_with_the_bitrate_of_a_config(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "robot.toml"
    cfg.write_text('[bus]\ninterface = "socketcan"\nchannel = "can0"\nbitrate = 250000\n\n'
                   "[chassis]\nlayout = \"b21\"\nbase_radius = 0.19\n\n"
                   + "".join(f"[[wheel]]\nnode_id = {n}\nvelocity_scale = 1000.0\n"
                             f"position_scale = 10000.0\n\n" for n in (1, 2, 3)))
    out = run_ok(["monitor", "--sim", "--config", str(cfg), "--duration", "1.2",
                  "--interval", "5"], capsys)
    [(_, rows, bus)] = tables(out)
    m = re.fullmatch(r"bus load: (\d+\.\d) kbit/s worst case over the last 1\.0 s "
                     r"\((\d+\.\d)% of 250 kbit/s\)", bus[0])
    assert m, bus[0]
    assert float(m.group(2)) == pytest.approx(float(m.group(1)) / 250 * 100, abs=0.1)
    assert rows["0x202"][0] == "RPDO1_node2"


def test_ctrl_c_ends_cleanly(monkeypatch: pytest.MonkeyPatch,
                             capsys: pytest.CaptureFixture[str]) -> None:
    calls = 0
    real_pause = monitor._pause

    def pause(seconds: float) -> None:
        nonlocal calls
        calls += 1
        if calls == 25:
            raise KeyboardInterrupt
        real_pause(seconds)

    monkeypatch.setattr(monitor, "_pause", pause)
    out = run_ok(["monitor", "--sim"], capsys)  # no --duration: until Ctrl-C
    title, rows, bus = tables(out)[-1]
    assert title.startswith("summary")
    assert rows["0x080"][0] == "SYNC"
    assert bus[0].startswith("bus load:")
    # the base was closed: the drives were disabled on the way out
    assert re.match(r"TargetVelocity=0 inc/s  Controlword=0x", rows["0x201"][3])


def test_terminal_output_is_a_live_table(monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    monkeypatch.setenv("COLUMNS", "160")
    out = run_ok(["monitor", "--sim", "--duration", "1.0"], capsys)
    assert "\x1b[?25l" in out  # rich's Live hides the cursor while it redraws
    assert "omnican monitor (live" in out
    assert "omnican monitor (summary" in out
    assert "┏━" in out and "┃" in out  # a rich table
    for text in ("SYNC", "RPDO1_node3", "TargetVelocity=", "PositionActual=", "bus load:"):
        assert text in out


# ------------------------------------------------------------------ a bus of its own


@pytest.fixture
def traffic(channel: str) -> Iterator[can.BusABC]:
    """Other nodes on the channel: SYNC every 10 ms, a heartbeat, a frame no DBC knows,
    one shorter than the DBC says, a remote request."""
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        bus.send_periodic(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False), 0.01)
        bus.send_periodic(can.Message(arbitration_id=0x702, data=b"\x05", is_extended_id=False),
                          0.1)
        bus.send_periodic(can.Message(arbitration_id=0x12345, data=b"\x01\x02\x03",
                                      is_extended_id=True), 0.05)
        bus.send_periodic(can.Message(arbitration_id=0x202, data=b"\x01\x02",  # too short
                                      is_extended_id=False), 0.05)
        bus.send_periodic(can.Message(arbitration_id=0x703, is_remote_frame=True, dlc=1,
                                      is_extended_id=False), 0.1)  # node guarding
        yield bus
    finally:
        bus.shutdown()


def test_listens_on_a_given_bus(traffic: can.BusABC, channel: str,
                                capsys: pytest.CaptureFixture[str]) -> None:
    out = run_ok(["monitor", "-i", "virtual", "-c", channel, "-b", "500000",
                  "--duration", "1.2"], capsys)
    live, (title, rows, bus) = tables(out)[0], tables(out)[-1]
    assert live[0].startswith("live, 1.0 s")
    assert title.startswith("summary") and f"virtual {channel}" in title
    assert rows["0x080"][0] == "SYNC"
    assert 50 <= rows["0x080"][2] <= 150
    assert rows["0x702"][0] == "Heartbeat_node2"
    assert rows["0x702"][3] == "NmtState=operational"
    assert rows["0x00012345"][0] == "?"
    assert rows["0x00012345"][3] == "01 02 03"
    assert rows["0x202"][3] == "01 02  (length 2, DBC says 6)"
    assert rows["0x703"][3] == "(remote request)"
    assert re.fullmatch(r"bus load: \d+\.\d kbit/s worst case over the last 1\.0 s "
                        r"\(\d+\.\d% of 500 kbit/s\)", bus[0])
    assert "frames" in bus[1]


def test_a_bus_that_does_not_open_is_a_runtime_error(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["monitor", "-i", "socketcan", "-c", "omnican-no-such-if", "--duration", "0.2"])
    assert code == 1
    assert one_line_error(capsys).startswith("omnican: error: cannot open CAN bus")


# ------------------------------------------------------------------ bad usage


@pytest.mark.parametrize("argv", [
    ["--duration", "-1"],
    ["--duration", "nan"],
    ["--duration", "0"],
    ["--interval", "inf"],
    ["--duration"],
])
def test_bad_arguments_exit_2_with_one_line(argv: list[str],
                                            capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["monitor", "--sim", *argv])
    assert exc.value.code == 2
    assert one_line_error(capsys).startswith("omnican monitor: error: ")


def test_missing_dbc(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["monitor", "--sim", "--dbc", "/nonexistent.dbc", "--duration", "0.1"]) == 2
    assert one_line_error(capsys) == "omnican: error: --dbc /nonexistent.dbc: no such file"


@pytest.mark.parametrize("name, text", [
    ("garbage.dbc", "this is not a DBC\n"),
    ("notes.txt", "BO_ 1 X: 8 Y\n"),
    ("broken.dbc", 'VERSION ""\nBO_ 513 RPDO1: 2 Host\n SG_ Controlword : 0|32@1+ (1,0) [0|1] "" X\n'),
])
def test_unreadable_dbc(tmp_path: Path, name: str, text: str,
                        capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / name
    path.write_text(text)
    assert main(["monitor", "--sim", "--dbc", str(path), "--duration", "0.1"]) == 2
    assert one_line_error(capsys).startswith(
        f"omnican: error: --dbc {path}: not a database cantools can read: ")


def test_bad_config(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["monitor", "--sim", "--config", str(tmp_path / "missing.toml"),
                 "--duration", "0.1"]) == 2
    assert "missing.toml" in one_line_error(capsys)
    bad = tmp_path / "bad.toml"
    bad.write_text("[chassis]\nbase_radius = -1\n")
    assert main(["monitor", "--sim", "--config", str(bad), "--duration", "0.1"]) == 2
    assert "bad.toml" in one_line_error(capsys)


def test_sim_with_bus_arguments(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["monitor", "--sim", "-c", "can0", "--duration", "0.1"]) == 2
    assert "--sim" in one_line_error(capsys)


# ------------------------------------------------------------------ pieces


def test_the_live_table_fits_100x30_with_the_bus_load_on_top() -> None:
    """Issue 31 item 10: at 100x30 the table was cut with '...' and the bus load, the
    headline figure, stayed hidden until exit; long signal lists folded rows."""
    import io

    from rich.console import Console

    from omnican.analysis.traffic import DEFAULT_DBC, TrafficCounter, load_dbc
    from omnican.cli.monitor import rich_table

    counter = TrafficCounter(load_dbc(DEFAULT_DBC), 500_000)
    ids = [0x080, *(base + n for base in (0x181, 0x281, 0x301, 0x381, 0x481, 0x581, 0x601,
                                          0x701) for n in (1, 2, 3)), 0x123, 0x124, 0x125]
    for can_id in ids:
        counter.on_message_received(can.Message(arbitration_id=can_id, data=bytes(8),
                                                is_extended_id=False))
    snap = counter.snapshot()
    assert len(snap.rows) > 30 - 8  # more ids than fit
    out = io.StringIO()
    console = Console(file=out, width=100, height=30, color_system=None)
    console.print(rich_table(snap, "omnican monitor (live, 1.0 s) on x", "?", 30, 100))
    lines = out.getvalue().rstrip("\n").split("\n")
    assert len(lines) <= 30 and max(len(line) for line in lines) <= 100, out.getvalue()
    assert lines[1].startswith("bus load:") and "% of 500 kbit/s" in lines[1]
    rows = [line for line in lines if re.match(r"│ 0x[0-9A-F]{3} ", line)]
    assert len(rows) == 30 - 8 and all(line.endswith("│") for line in rows), out.getvalue()
    assert lines[-1].startswith(f"... {len(snap.rows) - len(rows)} more ids")
