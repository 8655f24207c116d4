"""``omnican plot`` through its entry point (and the figure it draws)."""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib.image  # the test extra installs the plot extra's matplotlib
import pytest

from omnican import default_config
from omnican.cli import main
from omnican.cli import plot as plot_cli
from omnican.record import replay
from tests.support.helpers import one_error_line

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
WROTE = re.compile(r"wrote (\S+): (\S+) s, (\d+) frames, (\d+)/(\d+) complete SYNCs, (\d+) EMCY; "
                   r"end pose x=(\S+) y=(\S+) theta=(\S+); last states: node 1 SWITCH ON "
                   r"DISABLED, node 2 SWITCH ON DISABLED, node 3 SWITCH ON DISABLED")


@dataclass
class Recording:
    path: Path
    pose: dict[str, float]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    path = tmp_path_factory.mktemp("plot") / "arc.log"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        # In simulated time: the same recording on a loaded machine as on an idle one (in
        # real time, a slow shutdown drew a SWITCH ON DISABLED span long enough to label).
        code = main(["drive", "--sim", "--fast", "--vx", "0.3", "--wz", "0.8", "--duration",
                     "0.6", "--record", str(path), "--json"])
    assert code == 0
    return Recording(path, json.loads(out.getvalue())["pose"])


def test_plot_a_recording(recording: Recording, tmp_path: Path,
                          capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "arc.png"
    assert main(["plot", str(recording.path), "-o", str(out)]) == 0
    line = capsys.readouterr().out.strip()
    m = WROTE.fullmatch(line)
    assert m is not None, line
    assert m.group(1) == str(out)
    assert int(m.group(4)) > 50 and int(m.group(4)) >= int(m.group(5)) - 2
    assert m.group(6) == "0"
    # The end of the plotted trajectory is where the drive command said the base was.
    pose = recording.pose
    assert (float(m.group(7)), float(m.group(8)), float(m.group(9))) == pytest.approx(
        (pose["x"], pose["y"], pose["theta"]), abs=6e-5)
    assert out.read_bytes()[:8] == PNG_MAGIC
    image = matplotlib.image.imread(str(out))
    # 14 x 12.2 in at 100 dpi: three wheels, current, voltage, states
    assert image.shape[:2] == (1220, 1400)
    assert image.std() > 0.05  # not a blank canvas


def test_plot_svg_with_a_title(recording: Recording, tmp_path: Path) -> None:
    out = tmp_path / "arc.svg"
    assert main(["plot", str(recording.path), "-o", str(out), "--title", "my arc"]) == 0
    text = out.read_text()
    assert text.lstrip().startswith("<?xml") and "<svg" in text


def test_the_figure(recording: Recording) -> None:
    rep = replay.load(recording.path, default_config())
    truth = [(0.0, 0.0), (0.1, 0.01), (0.17, 0.05)]
    fig = plot_cli.build_figure(rep, "title here", truth)
    axes = fig.get_axes()
    assert len(axes) == 7  # trajectory, three wheels, current, voltage, states
    traj, wheels, (current, voltage), states = axes[0], axes[1:4], axes[4:6], axes[6]
    assert "title here" in fig._suptitle.get_text()
    assert traj.get_xlabel() == "x (m)" and traj.get_ylabel() == "y (m)"
    assert traj.get_aspect() == 1.0
    lines = {line.get_label(): line for line in traj.get_lines()}
    assert {"odometry", "simulator ground truth", "start", "end"} <= set(lines)
    assert lines["odometry"].get_xydata().tolist() == rep.poses[:, :2].tolist()
    assert lines["simulator ground truth"].get_xydata().tolist() == [list(p) for p in truth]
    for i, ax in enumerate(wheels):
        by_label = {line.get_label(): line for line in ax.get_lines()}
        assert by_label["target"].get_ydata().tolist() == rep.target_speed[i].tolist()
        assert by_label["actual (encoder)"].get_ydata().tolist() == \
            rep.actual_speed[:, i].tolist()
        assert ax.get_ylabel() == f"wheel {i} (node {i + 1})\nrim speed (m/s)"
    for ax, quantity, label in ((current, "current", "current (A)"),
                                (voltage, "voltage", "voltage (V)")):
        assert ax.get_ylabel() == label
        by_label = {line.get_label(): line for line in ax.get_lines()}
        for i in range(3):  # what the drives reported, as replay decodes it
            t, values = rep.health[quantity][i]
            assert len(t) > 3
            assert by_label[f"wheel {i}"].get_ydata().tolist() == values.tolist()
    moving = [float(abs(rep.health["current"][i][1]).max()) for i in range(3)]
    assert max(moving) > 0.5  # the wheels drew current while they drove
    assert all(23.0 < v < 24.01 for i in range(3) for v in rep.health["voltage"][i][1])
    assert [t.get_text() for t in states.get_yticklabels()] == [
        "node 1 (wheel 0)", "node 2 (wheel 1)", "node 3 (wheel 2)"]
    assert states.get_xlabel() == "time since the first frame (s)"
    legend = [t.get_text() for t in states.get_legend().get_texts()]
    assert "OPERATION ENABLED" in legend and "SWITCH ON DISABLED" in legend
    named = {t.get_text() for t in states.texts}
    assert named == {"OPERATION ENABLED"}  # the only state long enough to be written in


def test_the_figure_lists_events() -> None:
    rep = replay.decode([], default_config())
    assert plot_cli._events_text(rep) == ""
    rep2 = replay.Replay(**{**rep.__dict__, "emcy": (replay.EmcyEvent(1.5, 2, 0x2310, 3),),
                            "reboots": ((2.25, 3),)})
    assert plot_cli._events_text(rep2).splitlines() == [
        "events (dotted lines on the time plots):",
        "   1.50 s  node 2 EMCY 0x2310 continuous over-current",
        "   2.25 s  node 3 rebooted"]
    fig = plot_cli.build_figure(rep2, "empty")
    assert fig.get_axes()[0].texts[0].get_text() == "no complete position samples"


def test_plot_sim_overlays_the_ground_truth(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    drawn: list[tuple[Any, Any]] = []
    real = plot_cli.build_figure

    def keep(rep, title, truth=None):  # type: ignore[no-untyped-def]
        drawn.append((rep, truth))
        return real(rep, title, truth)

    monkeypatch.setattr(plot_cli, "build_figure", keep)
    out, rec = tmp_path / "demo.png", tmp_path / "demo.log"
    assert main(["plot", "--sim", "--fast", "-o", str(out), "--square", "0.1", "--sides", "1",
                 "--speed", "0.5", "--omega", "3", "--record", str(rec)]) == 0
    assert WROTE.fullmatch(capsys.readouterr().out.strip())
    assert out.read_bytes()[:8] == PNG_MAGIC
    rep, truth = drawn[0]
    assert rec.is_file() and replay.load(rec, default_config()).frames == rep.frames
    # One side and one left turn: the odometry and the (exact) simulator agree.
    x, y, theta = rep.poses[-1]
    assert x == pytest.approx(0.1, abs=0.01) and theta == pytest.approx(1.5708, abs=0.03)
    assert len(truth) > 20
    assert truth[-1] == pytest.approx((x, y), abs=0.002)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["/nonexistent.log", "-o", "x.png"], "recording not found: /nonexistent.log"),
        (["-o", "x.png"], "give a RECORDING to plot, or --sim for the demo"),
        (["REC", "--sim", "-o", "x.png"], "give a RECORDING to plot, or --sim for the demo"),
        (["REC", "-o", "x.png", "--sim-scale-error", "0.1"], "--sim-scale-error needs --sim"),
        (["--sim", "-o", "x.png", "--sim-radius-error", "0.9"], "must lie within +-0.5"),
        (["REC", "-o", "x.nope"], "-o x.nope: unknown image format 'nope'"),
        (["REC", "-o", "/nonexistent-dir/x.png"], "no such directory /nonexistent-dir"),
        (["REC", "-o", "x.png", "--config", "/nonexistent.toml"], "cannot read config"),
        (["REC"], "the following arguments are required: -o/--output"),
        (["REC", "-o", "x.png", "--sides", "5"], "argument --sides: invalid choice"),
    ],
)
def test_bad_usage_is_one_line_and_exit_2(argv: list[str], message: str, recording: Recording,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    argv = [str(recording.path) if a == "REC" else a for a in argv]
    with pytest.raises(SystemExit) as info:
        raise SystemExit(main(["plot", *argv]))
    assert info.value.code == 2
    assert message in one_error_line(capsys.readouterr().err)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("garbage.log", b"this is not candump\n", "garbage.log: not a readable .log recording"),
        ("garbage.blf", b"\x00" * 100, "garbage.blf: not a readable .blf recording"),
        ("empty.asc", b"", "empty.asc: no CAN frames in the recording"),
        ("data.xyz", b"1", "No read support for unknown log format \".xyz\""),
    ],
)
def test_unreadable_recordings_are_exit_2(name: str, content: bytes, message: str,
                                          tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / name
    path.write_bytes(content)
    assert main(["plot", str(path), "-o", str(tmp_path / "x.png")]) == 2
    assert message in one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "x.png").exists()


def test_a_recording_of_another_base_is_exit_2(recording: Recording, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "other.toml"
    wheels = "".join(f"[[wheel]]\nnode_id = {n}\nvelocity_scale = 1000.0\n"
                     "position_scale = 1000.0\n" for n in (21, 22, 23))
    config.write_text(f'[chassis]\nlayout = "b21"\nbase_radius = 0.2\n{wheels}')
    assert main(["plot", str(recording.path), "-o", str(tmp_path / "x.png"),
                 "--config", str(config)]) == 2
    assert one_error_line(capsys.readouterr().err) == (
        f"omnican: error: {recording.path}: no frames of nodes 21, 22, 23 (recorded on another "
        "base? give its --config)")


# ---------------------------------------------------------------- issue 31 item 16


@pytest.fixture(scope="module")
def zlac_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("plot") / "zlac.log"
    config = Path(__file__).resolve().parents[2] / "examples" / "zlac8015d.toml"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["drive", "--sim", "--fast", "--config", str(config), "--vx", "0.2",
                     "--duration", "0.5", "--record", str(path)]) == 0
    return path


def test_a_recording_that_does_not_match_the_config_is_said_so(
        zlac_recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A ZLAC recording plotted without its --config drew a 157,000 V DC link, speeds of
    0.0001 m/s and an empty trajectory, and exited 0."""
    out = tmp_path / "z.png"
    assert main(["plot", str(zlac_recording), "-o", str(out)]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert f"{zlac_recording}: the recording does not match the config: node 3 of the " \
           "config sent no frame" in line and "give its --config" in line, line
    assert not out.exists()
    config = Path(__file__).resolve().parents[2] / "examples" / "zlac8015d.toml"
    assert main(["plot", str(zlac_recording), "-o", str(out), "--config", str(config)]) == 0


def test_identical_traces_stay_visible_and_the_legend_arrows_match(
        zlac_recording: Path) -> None:
    """One DC link feeds every wheel: wheel 0's voltage was drawn under wheel 2's and could
    not be seen. The legend's heading arrow was grey; the arrows drawn are green and red."""
    from matplotlib.colors import to_rgba

    from omnican.config import load_config

    config = Path(__file__).resolve().parents[2] / "examples" / "zlac8015d.toml"
    rep = replay.load(zlac_recording, load_config(config))
    fig = plot_cli.build_figure(rep, "zlac")
    voltage = next(ax for ax in fig.get_axes() if ax.get_ylabel() == "voltage (V)")
    lines = [line for line in voltage.get_lines() if line.get_label().startswith("wheel")]
    assert len(lines) == 3
    assert lines[0].get_ydata().tolist() == lines[2].get_ydata().tolist()  # one DC link
    for under, over in itertools.pairwise(lines):
        # a line drawn over another is narrower: the one under shows at its edges
        assert over.get_zorder() > under.get_zorder()
        assert over.get_linewidth() < under.get_linewidth() - 1.0
    traj = fig.get_axes()[0]
    handles, labels = traj.get_legend_handles_labels()
    colours = {label: to_rgba(h.get_color()) for h, label in zip(handles, labels, strict=True)
               if label.startswith("heading")}
    assert colours == {"heading at the start": to_rgba("green"),
                       "heading at the end": to_rgba("red")}


@pytest.mark.parametrize(("side", "words"), [("1e308", "beyond what one motion may take"),
                                             ("1e6", "one motion may take at most 24 h")])
def test_plot_sim_refuses_a_square_no_base_drives_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], side: str, words: str) -> None:
    """As drive --square does: one line, exit 2, nothing opened (was a ValueError
    traceback for 1e308, and hours of simulation for 1e6)."""
    assert main(["plot", "--sim", "--square", side, "-o", str(tmp_path / "p.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "motion refused" in err and words in err
    assert not (tmp_path / "p.png").exists()
