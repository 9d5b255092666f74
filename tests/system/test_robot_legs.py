"""The robot demo forth and back with real processes (launch/robot.yaml): ``passes:=3`` ends
by itself with every stamp after the one before, ``loop:=true`` streams until Ctrl-C."""

from __future__ import annotations

import json
import os
import re
import signal
from pathlib import Path

import numpy as np

from tests.system.test_first_hour import Launch
from vibrissa.formats.scene_file import load_scene
from vibrissa.msgs import EndOfStream
from vibrissa.msgs.codec import decode
from vibrissa.wire.bag import BagReader

LAUNCH = Path(__file__).parents[2] / "launch"
DOMAIN = 8260 + os.getpid() % 12 * 128  # beside test_first_hour's domains
SAMPLES = len(load_scene(LAUNCH / "robot" / "scene.yaml").path.t)


def test_three_passes_end_by_themselves_with_stamps_running_on(tmp_path: Path) -> None:
    out = tmp_path / "out"
    launch = Launch(LAUNCH / "robot.yaml", f"out:={out}", "passes:=3", "epoch:=0",
                    domain=DOMAIN)
    assert launch.wait(900) == 0, launch.text()
    wrenches = [decode(r.payload) for r in BagReader(out / "robot.mcap")
                if r.topic == "/robot/wrench"]
    assert isinstance(wrenches[-1], EndOfStream), launch.text()
    stamps = np.array([w.stamp for w in wrenches[:-1]])
    assert len(stamps) == 3 * SAMPLES - 2
    assert np.all(np.diff(stamps) > 0)
    assert [w.seq for w in wrenches[:-1]] == list(range(len(stamps)))
    assert f"simulated 8 whisker(s) x {3 * SAMPLES - 2} path samples" in launch.text()
    assert (out / "report.json").exists()


def test_a_loop_streams_until_ctrl_c(tmp_path: Path) -> None:
    out = tmp_path / "out"
    launch = Launch(LAUNCH / "robot.yaml", f"out:={out}", "loop:=true",
                    "rate:=4000", domain=DOMAIN + 2)
    cycle = 2 * SAMPLES - 2

    def page_so_far() -> str:
        """map.html while the streams go on ("" before it is written; each write is whole)."""
        page = out / "map.html"
        return page.read_text() if page.exists() else ""

    arrays, rc = launch.stream_then_stop(  # into the third cycle, and a map page written
        "/robot/wrench", DOMAIN + 2,
        lambda got: len(got) >= 2 * cycle + 100 and "map so far" in page_so_far())
    stamps = [array.stamp for array in arrays]
    text = launch.text()
    assert np.all(np.diff(stamps) > 0)
    assert rc == 128 + signal.SIGINT, text
    assert re.search(r"wrench_source\] .*\d+ messages and EndOfStream", text), text
    assert re.search(r"wrench_source\s+stopped by launcher \(exit 0\)", text), text
    assert "Traceback" not in text
    report = json.loads((out / "report.json").read_text())
    assert (report["final"], report["ended_by"]) == (True, "stop")
    assert f"final map (ended by stop): {report['n_points']} contact points" in (
        out / "map.html").read_text()
