"""The example node of docs/WRITING_NODES.md (docs/examples/phase_filter.py) added, as written,
to the real demo graph (launch/demo.yaml) and the real robot graph (launch/robot.yaml): it takes
the reconstructor's contacts, republishes a message per message with the rows of its phase,
rejects nothing, and the launch exits 0. Real processes on loopback; the launch files are the
packaged ones with the example's entry added, written to tmp_path."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from tests.system.test_system_pipeline import LAUNCH, Launch, Probe, entries, node, set_param
from vibrissa.msgs import ContactPointArray, EndOfStream
from vibrissa.status import ContactPhase

EXAMPLE = Path(__file__).parents[2] / "docs" / "examples" / "phase_filter.py"
DEADLINE_S = 900.0
"""Generous: the robot graph simulates its scene on start; a machine at load 20 is slow."""


def with_example(launch_file: str, namespace: str) -> list[dict[str, Any]]:
    """The packaged launch file's entries, the example node added in ``namespace`` (its
    defaults: ``contact`` in, ``tip_contact`` out), and the reconstructor waiting for it too, so
    that it hears the stream from its first message."""
    launch = entries(launch_file)
    reconstructor = node(launch, "reconstructor")
    waits = next(p["value"] for p in reconstructor["param"] if p["name"] == "wait_for")
    set_param(reconstructor, "wait_for", [*waits, f"{namespace}/phase_filter"])
    launch.append({"node": {
        "cmd": ["$(python)", str(EXAMPLE)], "name": "phase_filter", "namespace": namespace,
        "finite": True, "param": [{"name": "phase", "value": "tip"}]}})
    return launch


@pytest.mark.parametrize(("launch_file", "namespace", "words"), [
    ("demo.yaml", "/whisker0", ["step:=0.004"]),
    ("robot.yaml", "/robot", [f"scene:={LAUNCH / 'robot' / 'scene.yaml'}"]),
])
def test_the_example_node_runs_in_the_graph(tmp_path: Path, launch_file: str, namespace: str,
                                            words: list[str]) -> None:
    out = tmp_path / "out"
    launch = Launch(tmp_path, with_example(launch_file, namespace), f"out:={out}", *words)
    probe = Probe(launch.endpoints(), [f"{namespace}/tip_contact"])
    try:
        filtered, eos = probe.collect(DEADLINE_S)
        rc = launch.wait(DEADLINE_S)
    finally:
        probe.close()
        launch.kill()
    text = launch.text()
    assert rc == 0, text
    assert not re.search(r"rejected [1-9]|rejected message", text), text
    assert "data did not arrive in full" not in text, text
    # what it republished: a message per input message, only tip rows, then the end
    assert isinstance(eos, EndOfStream) and eos.source == f"{namespace}/phase_filter"
    assert filtered and eos.count == len(filtered)
    assert [m.seq for m in filtered] == sorted(m.seq for m in filtered)
    assert all(isinstance(m, ContactPointArray) for m in filtered)
    rows = sum(len(m.whisker_ids) for m in filtered)
    assert rows > 0 and all((m.phase == ContactPhase.TIP).all() for m in filtered)
    # its own count of what it received, against the map of every contact
    match = re.search(r"\[phase_filter\] .*kept (\d+) tip contacts, dropped (\d+)", text)
    assert match, text
    kept, dropped = int(match.group(1)), int(match.group(2))
    assert kept == rows and dropped > 0
    report = json.loads((out / "report.json").read_text())
    assert kept + dropped == report["n_points"]
    # the launch's summary: everything it received was taken, every message republished
    summary = re.search(r"^\S*\s*phase_filter\s+exit 0 .*published (\d+)\s+received (\d+)(.*)$",
                        text, flags=re.M)
    assert summary, text
    published, received = int(summary.group(1)), int(summary.group(2))
    assert published == len(filtered) and received == published + 1  # and its input's end
    assert "lost" not in summary.group(3) and "rejected" not in summary.group(3)
