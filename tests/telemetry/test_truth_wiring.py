"""The simulator's ground truth in a base's telemetry (omnican.telemetry.attach.add_truth):
kept until a feed is made, so a base that no front end or recording asks for makes no
feed (nor imports the telemetry); a feed made before or after has the truth."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from omnican.telemetry.attach import add_truth, feed_of
from tests.support.helpers import lockstep_rig

ROOT = Path(__file__).resolve().parents[2]


def test_a_feed_made_after_the_truth_carries_it(channel: str) -> None:
    with lockstep_rig(channel) as (clock, sim, base):
        add_truth(base, sim)
        assert base.attachments.get("telemetry") is None  # nothing asked for one yet
        feed = feed_of(base)
        assert feed.truth is sim
        clock.sleep(0.05)
        assert feed._sample(None, 0).true_pose == sim.true_pose


def test_a_feed_made_before_the_truth_carries_it_too(channel: str) -> None:
    with lockstep_rig(channel) as (_, sim, base):
        feed = feed_of(base)
        assert feed.truth is None
        add_truth(base, sim)
        add_truth(base, sim)  # again: the same
        assert feed.truth is sim and feed_of(base) is feed


def test_a_base_beside_a_simulator_without_front_ends_imports_no_telemetry() -> None:
    """``drive --sim --fast`` with nothing attached: the feed's modules stay unloaded."""
    code = ("import sys\nfrom omnican.cli import main\n"
            "code = main(['drive', '--sim', '--fast', '--vx', '0.1', '--duration', '0.1',"
            " '--json'])\n"
            "print(sorted(m for m in sys.modules if m.startswith('omnican.telemetry.')))\n"
            "sys.exit(code)\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[-1] == "['omnican.telemetry.attach']"
