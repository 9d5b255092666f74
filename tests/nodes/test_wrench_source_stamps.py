"""The wrench source's stamps: a simulated stream is stamped from a stated epoch (``epoch_s``,
the launch files' ``epoch`` argument, by default the time the launch started)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import yaml

from vibrissa.launch.description import load_launch_file, node_params
from vibrissa.nodes.wrench_source import WrenchSourceParams, clock_from

LAUNCH = Path(__file__).parents[2] / "launch"
EPOCH = 1_767_225_600.25  # 2026-01-01T00:00:00.25Z
SIMULATED = {"demo.yaml": "sim", "record_demo.yaml": "sim", "robot.yaml": "scene",
             "view.yaml": "scene", "explore.yaml": "scene", "robot_host.yaml": "scene"}


def test_the_sim_clock_reads_the_epoch_first_then_the_time_since() -> None:
    clock = clock_from(EPOCH)
    first = clock()
    later = [clock() for _ in range(1000)]
    assert first == EPOCH
    assert later == sorted(later) and later[0] >= EPOCH
    assert later[-1] - EPOCH < 60.0  # the time since the first sample, not since 1970


@pytest.mark.parametrize("epoch_s", [float("nan"), float("inf"), -1.0, 2.0**31])
def test_an_epoch_outside_what_a_ros2_time_holds_is_refused(epoch_s: float) -> None:
    with pytest.raises(ValueError, match="parameter 'epoch_s' must be s since the Unix epoch"):
        WrenchSourceParams(epoch_s=epoch_s)


def test_every_simulated_source_of_a_launch_file_takes_its_epoch_argument() -> None:
    simulated: dict[str, list[object]] = {}
    for path in LAUNCH.glob("*.yaml"):
        for entry in yaml.safe_load(path.read_text())["launch"]:
            body = entry.get("node", {})
            params = {p["name"]: p["value"] for p in body.get("param", [])}
            if body.get("exec") == "wrench_source" and params["mode"] != "replay":
                simulated.setdefault(path.name, []).append(params.get("epoch_s"))
    assert simulated == {name: ["$(var epoch)"] for name in SIMULATED}


@pytest.mark.parametrize("name", sorted(SIMULATED))
def test_the_epoch_defaults_to_the_launch_start_and_reaches_the_source(name: str) -> None:
    before = time.time()
    default = load_launch_file(LAUNCH / name)
    after = time.time()
    explicit = load_launch_file(LAUNCH / name, {"epoch": repr(EPOCH)})
    for description, low, high in ((default, before, after), (explicit, EPOCH, EPOCH)):
        (source,) = [n for n in description.nodes if n.executable == "wrench_source"]
        params = node_params(source)
        assert params["mode"] == SIMULATED[name]
        assert low <= params["epoch_s"] <= high, (name, params["epoch_s"])
        assert WrenchSourceParams(epoch_s=params["epoch_s"]).epoch_s == params["epoch_s"]
