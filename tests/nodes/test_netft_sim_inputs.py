"""The simulated Net F/T fed by a scene (``scene``/``simulated``/``whisker``: the ``vibrissa
simulate`` results of a whisker whose sensor sits off its clamp), read by the driver node (a
real process) over loopback UDP: the driver publishes the Step 1 wrench to the counts'
quantisation; ``bias_at_start`` removes a constant sensor offset when the rod starts free and
refuses when it starts in contact. Every receive has a timeout."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.nodes.test_netft_driver import CPF, Watch, driver
from vibrissa.calibration import clamp_to_sensor, sensor_to_clamp
from vibrissa.cli.main import main
from vibrissa.formats.scene_file import load_scene
from vibrissa.formats.scene_results import read_results
from vibrissa.msgs import WhiskerWrenchArray
from vibrissa.nodes.netft_sim import NetFTSimParams, open_device
from vibrissa.wire import Endpoints

# A ball passed along -x: `late` is free for its first 110 path samples, `early` touches the
# ball from its third on. `late`'s sensor sits 12 mm below its clamp, turned and shifted.
SCENE = """\
mu: 0.2
objects:
  - {name: ball, shape: sphere, radius_m: 0.015, position_m: [0.0, 0.0, 0.04]}
whiskers:
  - name: late
    length_m: 0.05
    ei_nm2: 2.3e-4
    mount: {position_m: [0.0, 0.0, 0.0]}
    sensor: {position_m: [0.003, -0.002, -0.012],
             quaternion_xyzw: [0.1, -0.2, 0.3, 0.9273618495495703]}
  - name: early
    length_m: 0.05
    ei_nm2: 2.3e-4
    mount: {position_m: [-0.029, 0.0, 0.0]}
path: path.csv
"""
SAMPLES = 160
Q = 1 / CPF  # one count, N or N m (counts_per_force = counts_per_torque = CPF)
OFFSET = (0.02, -0.015, 0.01, 0.001, -0.0005, 0.0008)  # the sensor's own bias, S: below the
# driver's free-rod thresholds (0.05 N, 0.005 N m), so that a free rod reads as free


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """SCENE.yaml with its path; its `vibrissa simulate` results in ``out`` beside it."""
    folder = tmp_path_factory.mktemp("scene")
    x = np.linspace(0.045, 0.0, SAMPLES)
    rows = [f"{0.01 * i},{x[i]},0,0,0,0,0,1" for i in range(SAMPLES)]
    (folder / "path.csv").write_text("\n".join(["t,x,y,z,qx,qy,qz,qw", *rows]) + "\n")
    (folder / "scene.yaml").write_text(SCENE)
    assert main(["simulate", str(folder / "scene.yaml"), "-o", str(folder / "out"),
                 "--workers", "1"]) == 0
    return folder / "scene.yaml"


@pytest.fixture
def watch(endpoints: Endpoints, context: Any) -> Iterator[Watch]:
    w = Watch(endpoints, context)
    yield w
    w.close()


def step1(scene: Path, whisker: str) -> np.ndarray:
    """(N, 6) the whisker's f0 (N), m0 (N m) in its clamp frame, read back from the results."""
    result = next(r for r in read_results(scene.parent / "out", load_scene(scene)) if r.name == whisker)
    assert np.isfinite(result.f0_n).all(), "no unresolved samples in this scene"
    return np.hstack([result.f0_n, result.m0_nm])


def sim_params(scene: Path, whisker: str, **values: Any) -> NetFTSimParams:
    return NetFTSimParams(scene=str(scene), simulated=str(scene.parent / "out"), whisker=whisker,
                          port=0, rate_hz=1000.0, counts_per_force=CPF, counts_per_torque=CPF,
                          **values)


def aligned_error(got: list[WhiskerWrenchArray], expected: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """|f0| and |m0| errors (M,) of the published wrenches against the rows of ``expected``
    that the device played for them: one row per record, looping, from an offset found here
    (the test subscribes after the stream has begun)."""
    assert [w.seq for w in got] == list(range(got[0].seq, got[0].seq + len(got))), "gaps"
    wrench = np.array([np.concatenate([w.f0[0], w.m0[0]]) for w in got])  # one row each
    rows = (np.arange(len(expected))[:, None] + np.arange(len(got))) % len(expected)
    worst = np.abs(wrench[None] - expected[rows]).max(axis=(1, 2))
    error = wrench - expected[rows[int(np.argmin(worst))]]
    return np.linalg.norm(error[:, :3], axis=1), np.linalg.norm(error[:, 3:], axis=1)


def bounds(scene: Path, whisker: str, counts: float) -> tuple[float, float]:
    """Largest |f0|, |m0| errors of ``counts`` counts per component of the reading in S: a
    rotation keeps the force's norm; the moment gains p_CS x (R_CS f_S)."""
    X_CS = next(w for w in load_scene(scene).whiskers if w.name == whisker).X_CS
    f = counts * Q * np.sqrt(3) * (1 + 1e-9)
    return f, f * (1 + float(np.linalg.norm(X_CS.translation)))


def test_the_driver_publishes_the_step1_wrench_of_a_scene_whisker(
        tmp_path: Path, scene: Path, endpoints: Endpoints, watch: Watch) -> None:
    expected = step1(scene, "late")
    X_CS = next(w for w in load_scene(scene).whiskers if w.name == "late").X_CS
    _, m_S = clamp_to_sensor(expected[:, :3], expected[:, 3:], X_CS)
    assert np.abs(-m_S - expected[:, 3:]).max() > 1000 * Q  # a driver that took S for C fails
    with open_device(sim_params(scene, "late")) as device, \
            driver(tmp_path, endpoints, device, whisker="late", robot=str(scene)):
        got = watch.take(2 * SAMPLES)
    assert all(w.frame_ids == ["late/clamp"] for w in got)
    df, dm = aligned_error(got, expected)
    max_f, max_m = bounds(scene, "late", 0.5)  # the device rounds to the nearest count
    assert df.max() <= max_f and dm.max() <= max_m, (df.max(), dm.max())
    assert np.linalg.norm(expected[:, :3], axis=1).max() > 0.1  # the window holds the contact


def test_bias_at_start_removes_the_sensor_offset_of_a_free_rod(
        tmp_path: Path, scene: Path, endpoints: Endpoints, watch: Watch) -> None:
    with open_device(sim_params(scene, "late", bias=OFFSET)) as device, \
            driver(tmp_path, endpoints, device, whisker="late", robot=str(scene),
                   bias_at_start=True, free_samples=20):
        counters = watch.until(lambda c: c.get("biases", 0) >= 1)
        # the status after next: the wrenches before the bias were sent well before it
        watch.until(lambda c: c["records"] > counters["records"])
        while watch.wrenches.receive(0) is not None:  # anything from before the bias
            pass
        got = watch.take(2 * SAMPLES)
        assert device.stats.biases == 1 and counters["bias_refused"] == 0
    df, dm = aligned_error(got, step1(scene, "late"))
    # raw counts minus the raw counts at the bias: each rounded, so up to one count apart
    max_f, max_m = bounds(scene, "late", 1.0)
    assert df.max() <= max_f and dm.max() <= max_m, (df.max(), dm.max())


def test_bias_at_start_is_refused_when_the_rod_starts_in_contact(
        tmp_path: Path, scene: Path, endpoints: Endpoints, watch: Watch) -> None:
    expected = step1(scene, "early")
    assert np.linalg.norm(expected[:50, :3], axis=1).max() > 0.1  # loaded within free_samples
    with open_device(sim_params(scene, "early", bias=OFFSET)) as device, \
            driver(tmp_path, endpoints, device, whisker="early", robot=str(scene),
                   bias_at_start=True, free_samples=50) as proc:
        counters = watch.until(lambda c: c.get("bias_refused", 0) >= 1)
        got = watch.take(2 * SAMPLES)
        assert counters["biases"] == 0 and device.stats.biases == 0
        proc.terminate()
        _, err = proc.communicate(timeout=60)  # its shutdown, on a loaded machine
    assert "bias refused: the rod is not free" in err
    # not tared: the wrench still holds the sensor's offset, as the clamp's reaction
    X_CS = next(w for w in load_scene(scene).whiskers if w.name == "early").X_CS  # identity
    f_b, m_b = sensor_to_clamp(np.array(OFFSET[:3]), np.array(OFFSET[3:]), X_CS)
    df, dm = aligned_error(got, expected + np.concatenate([f_b, m_b]))
    max_f, max_m = bounds(scene, "early", 0.5)
    assert df.max() <= max_f and dm.max() <= max_m, (df.max(), dm.max())


def test_a_whisker_not_in_the_scene_is_one_line_and_status_2(
        scene: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "netft", "--port", "0", "--scene", str(scene), "--simulated",
                 str(scene.parent / "out"), "--whisker", "w9"]) == 2
    err = capsys.readouterr().err
    assert err == f"vibrissa sim netft: error: whisker 'w9' is not in {scene} (late, early)\n"
