"""The robot demo with a drifting odometry and the localizer, real processes through the launcher
(launch/robot.yaml ``odom_drift:=0.02``): the run ends cleanly with the contacts mapped in
``map``, the report's localization against the truth, and a truth file whose odometry drifts
from its first pose; the same seed with ``localize:=false`` maps the contacts as the odometry
placed them, further from the true surfaces (computed here from the scene file's objects); a
replay of the localized run's bag gives its cloud bit for bit; and ``odom_drift:=0.0`` (the
odom/map graph without drift) gives the default graph's cloud bit for bit."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.system.test_first_hour import Launch
from vibrissa.formats.scene_file import load_scene
from vibrissa.formats.truth_poses import read_truth

LAUNCH = Path(__file__).parents[2] / "launch"
SCENE = LAUNCH / "robot" / "scene.yaml"
DOMAIN = 8210 + os.getpid() % 12 * 128  # +0..+4: between test_first_hour's domains
DRIFT = ("passes:=2", "odom_drift:=0.02", "seed:=4")  # seed 4: a drift of 26 mm at the end

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1300)]  # up to two launches' deadlines


def launch(out: Path, *words: str, domain: int) -> dict[str, Any]:
    """A run of launch/robot.yaml into ``out``: its exit status, output and report."""
    run = Launch(LAUNCH / "robot.yaml", f"out:={out}", *words, domain=domain)
    rc = run.wait(600)
    report = out / "report.json"
    return {"rc": rc, "text": run.text(), "out": out,
            "report": json.loads(report.read_text()) if report.is_file() else None}


def cloud_points(path: Path) -> np.ndarray:
    """x, y, z (N, 3) of a binary little-endian PLY of doubles (formats/ply.py's layout)."""
    header, _, body = path.read_bytes().partition(b"end_header\n")
    lines = header.decode("ascii").splitlines()
    assert "format binary_little_endian 1.0" in lines
    n = int(next(line.split()[-1] for line in lines if line.startswith("element vertex")))
    props = [line.split() for line in lines if line.startswith("property")]
    assert all(p[1] == "double" for p in props) and [p[2] for p in props[:3]] == ["x", "y", "z"]
    return np.frombuffer(body, "<f8", n * len(props)).reshape(n, len(props))[:, :3]


def mean_distance_m(cloud: Path) -> float:
    """The cloud's mean distance to the nearest of the scene's true surfaces, m."""
    points = cloud_points(cloud)
    surfaces = [obj.surface(1.0) for obj in load_scene(SCENE).objects]
    return float(np.min([np.abs(s.signed_distance(points)) for s in surfaces], axis=0).mean())


@pytest.fixture(scope="module")
def localized(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return launch(tmp_path_factory.mktemp("localized"), *DRIFT, domain=DOMAIN)


@pytest.fixture(scope="module")
def uncorrected(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return launch(tmp_path_factory.mktemp("uncorrected"), *DRIFT, "localize:=false",
                  domain=DOMAIN + 1)


def test_the_localizer_corrects_the_drift_and_the_map_is_in_map(localized: dict[str, Any]) -> None:
    assert localized["rc"] == 0, localized["text"]
    report = localized["report"]
    loc = report["localization"]
    assert loc is not None and loc["corrections"] >= 1, loc
    assert loc["true_drift_m"] > 0 and loc["error_m"] is not None, loc
    assert report["frames"] and all(f["frame_id"] == "map" for f in report["frames"])
    truth = read_truth(localized["out"] / "truth_poses.csv")
    assert len(truth.stamp_s) > 1000
    assert np.array_equal(truth.p_odom_m[0], truth.p_map_m[0])
    assert np.array_equal(truth.q_odom[0], truth.q_map[0])
    assert np.abs(truth.p_odom_m - truth.p_map_m).max() > 1e-3  # drifted by millimetres


def test_without_the_localizer_the_cloud_is_further_from_the_true_surfaces(
        localized: dict[str, Any], uncorrected: dict[str, Any]) -> None:
    assert uncorrected["rc"] == 0, uncorrected["text"]
    loc = uncorrected["report"]["localization"]
    assert loc is not None and loc["map_to_odom_m"] == [0, 0], loc
    assert localized["rc"] == 0, localized["text"]
    corrected = mean_distance_m(localized["out"] / "cloud.ply")
    drifted = mean_distance_m(uncorrected["out"] / "cloud.ply")
    assert drifted > corrected, (drifted, corrected)


def test_a_replay_of_the_localized_bag_gives_the_same_cloud(localized: dict[str, Any],
                                                             tmp_path: Path) -> None:
    assert localized["rc"] == 0, localized["text"]
    replay = launch(tmp_path / "replay", "mode:=replay", f"bag:={localized['out'] / 'robot.mcap'}",
                    "odom_drift:=0.02", domain=DOMAIN + 2)
    assert replay["rc"] == 0, replay["text"]
    cloud = (replay["out"] / "cloud.ply").read_bytes()
    assert cloud == (localized["out"] / "cloud.ply").read_bytes()


def test_a_zero_drift_maps_as_the_default_graph(tmp_path: Path) -> None:
    default = launch(tmp_path / "default", "passes:=1", domain=DOMAIN + 3)
    zero = launch(tmp_path / "zero", "passes:=1", "odom_drift:=0.0", domain=DOMAIN + 4)
    assert default["rc"] == 0, default["text"]
    assert zero["rc"] == 0, zero["text"]
    assert "'localizer'" in zero["text"] and "'localizer'" not in default["text"]
    assert [f["frame_id"] for f in zero["report"]["frames"]] == ["map"]
    assert (zero["out"] / "cloud.ply").read_bytes() == (default["out"] / "cloud.ply").read_bytes()
