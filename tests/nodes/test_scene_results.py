"""The results of ``vibrissa simulate`` read back (`vibrissa.formats.scene_results`) and played
by the wrench source's mode ``scene`` with ``simulated``: the arrays bit for bit, the same
messages as after simulating on start, and one clear error per bad folder (socket-free)."""

from __future__ import annotations

import csv
import json
import logging
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from vibrissa.formats.scene_file import SceneError, load_scene
from vibrissa.formats.scene_results import read_results, write_results
from vibrissa.msgs.codec import encode
from vibrissa.nodes.wrench_source import WrenchSourceParams, run_scene, scene_events, scene_stream
from vibrissa.runtime import ParamError, load_params
from vibrissa.scene import SamplePhase, Scene, WhiskerResult, simulate

# A cup the whiskers snap off (the tilted one then lands on it again), and a ball further on
# (tests/core/test_scene.py); a third whisker's clamp passes through both: unresolved samples,
# NaN wrenches.
SCENE = """\
mu: 0.2
objects:
  - {name: cup, shape: paraboloid, a_per_m: 10.0, b_per_m: 20.0, h_m: 0.02}
  - {name: ball, shape: sphere, radius_m: 0.015, position_m: [-0.125, 0.0, 0.04]}
whiskers:
  - {name: plain, length_m: 0.05, ei_nm2: 2.0e-5, mount: {}}
  - {name: tilted, length_m: 0.04, ei_nm2: 1.0e-5,
     mount: {position_m: [0.0, 0.005, 0.0], quaternion_xyzw: [0.04997917, 0, 0, 0.99875026]}}
  - {name: buried, length_m: 0.03, ei_nm2: 1.0e-5, mount: {position_m: [0.0, 0.0, 0.04]}}
path: path.csv
"""
SAMPLES = 300


def write_scene(folder: Path, dt: float = 0.01) -> Path:
    x = np.linspace(0.06, -0.165, SAMPLES).tolist()
    (folder / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + "".join(
        f"{dt * i!r},{x[i]!r},0,0,0,0,0,1\n" for i in range(SAMPLES)))
    (folder / "scene.yaml").write_text(SCENE)
    return folder / "scene.yaml"


@dataclass
class Simulated:
    scene_file: Path
    scene: Scene
    results: list[WhiskerResult]
    out: Path


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> Simulated:
    """The scene simulated once and written as ``vibrissa simulate -o out`` writes it."""
    folder = tmp_path_factory.mktemp("scene")
    scene_file = write_scene(folder)
    scene = load_scene(scene_file)
    results = simulate(scene, workers=1)
    write_results(folder / "out", scene, results)
    return Simulated(scene_file, scene, results, folder / "out")


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal dtype, shape, NaN positions, and every other element bit for bit (-0.0 too)."""
    if a.dtype != b.dtype or a.shape != b.shape:
        return False
    if a.dtype.kind != "f":
        return bool(np.array_equal(a, b))
    nan = np.isnan(a)
    return bool(np.array_equal(nan, np.isnan(b)) and a[~nan].tobytes() == b[~nan].tobytes())


def test_read_results_gives_back_the_arrays_simulate_returned(simulated: Simulated) -> None:
    read = read_results(simulated.out, simulated.scene)
    assert [r.name for r in read] == ["plain", "tilted", "buried"]
    for got, want in zip(read, simulated.results, strict=True):
        assert got.name == want.name
        for key in ("t", "phase", "s1_m", "f0_n", "m0_nm", "p_W_m", "object", "refined"):
            assert same_bits(getattr(got, key), getattr(want, key)), key
            assert np.array_equal(getattr(got, key), getattr(want, key), equal_nan=True), key
        assert got.episodes == want.episodes and got.counts() == want.counts()
    # what makes the round trip worth checking: NaN wrenches, points and arc lengths, objects
    tilted, buried = simulated.results[1:]
    assert np.any(buried.phase == SamplePhase.UNRESOLVED) and np.isnan(buried.f0_n).any()
    assert set(tilted.object.tolist()) == {-1, 0, 1} and len(tilted.episodes) == 3
    assert any(e.phase_changes for e in tilted.episodes)
    assert [e.start for e in tilted.episodes] == ["touch", "landing", "touch"]


def test_results_written_before_the_refined_column_and_the_scene_digest_still_read(
        simulated: Simulated, tmp_path: Path) -> None:
    folder = tmp_path / "out"
    shutil.copytree(simulated.out, folder)
    for name in ("plain", "tilted"):
        edit_csv(folder / f"{name}.csv", lambda rows: [row.pop() for row in rows])
    summary = json.loads((folder / "summary.json").read_text())
    del summary["scene_sha256"]
    (folder / "summary.json").write_text(json.dumps(summary))
    for got, want in zip(read_results(folder, simulated.scene), simulated.results, strict=True):
        assert not got.refined.any() and len(got.refined) == len(want.t)
        assert same_bits(got.f0_n, want.f0_n) and np.array_equal(got.phase, want.phase)


def stream(scene: Scene, results: list[WhiskerResult], params: WrenchSourceParams
           ) -> list[tuple[float, bytes]]:
    return [(t, encode(msg)) for t, msg in scene_stream(scene, results, params)]


def test_the_read_results_play_as_the_simulated_ones(simulated: Simulated) -> None:
    params = load_params(WrenchSourceParams, overrides={
        "mode": "scene", "scene": str(simulated.scene_file), "simulated": str(simulated.out),
        "pose_rate_hz": "40", "pose_delay_s": "0.05", "noise_force_n": "1e-4", "seed": "3"})
    read = read_results(params.simulated, simulated.scene)
    played = stream(simulated.scene, read, params)
    assert played == stream(simulated.scene, simulated.results, params)
    assert len(played) > SAMPLES


@dataclass
class FakePublisher:
    topic: str
    sent: list[Any] = field(default_factory=list)

    def publish(self, msg: Any) -> None:
        self.sent.append(msg)

    def publish_end_of_stream(self, source: str) -> None:
        self.sent.append("EOS")


@dataclass
class FakeNode:
    """What `run_scene` uses of a `vibrissa.runtime.Node`, without sockets."""

    fqn: str = "/robot/wrench_source"
    stop_requested: bool = False
    publishers: dict[str, FakePublisher] = field(default_factory=dict)

    def create_publisher(self, topic: str, *args: Any, **kwargs: Any) -> FakePublisher:
        return self.publishers.setdefault(topic, FakePublisher(topic))

    def set_state(self, state: str, detail: str = "") -> None:
        pass


def test_run_scene_plays_the_folder_and_says_so(simulated: Simulated,
                                                caplog: pytest.LogCaptureFixture) -> None:
    params = WrenchSourceParams(mode="scene", scene=str(simulated.scene_file),
                                simulated=str(simulated.out))
    node = FakeNode()
    with caplog.at_level(logging.INFO):
        sent = run_scene(node, params)  # type: ignore[arg-type]
    assert f"read 3 whisker(s) x {SAMPLES} path samples from {simulated.out} in " in caplog.text
    expected = [msg for _, msg in scene_stream(simulated.scene, simulated.results, params)]
    got = node.publishers["wrench"].sent[:-1] + node.publishers["/robot/pose"].sent[:-1]
    assert len(expected) == len(got)
    assert sorted(map(encode, got)) == sorted(map(encode, expected))
    # the jumps of the results read back, as the simulation's own give them
    jumps = [msg for _, msg in scene_events(simulated.scene, simulated.results, params)]
    told = node.publishers["events"].sent
    assert jumps and told[-1] == "EOS"
    assert [encode(m) for m in told[:-1]] == [encode(m) for m in jumps]
    assert sent == len(expected) + len(jumps)


def edit_csv(path: Path, edit: Callable[[list[list[str]]], None]) -> None:
    with path.open(newline="") as handle:
        rows = list(csv.reader(handle))
    edit(rows)
    with path.open("w", newline="") as handle:
        csv.writer(handle, lineterminator="\n").writerows(rows)


def first_row(rows: list[list[str]], phase: str) -> int:
    return next(i for i, row in enumerate(rows) if i and row[1] == phase)


def drop_pz(rows: list[list[str]]) -> None:
    for row in rows:
        del row[11]


def set_cell(row: int | str, column: int, text: str) -> Callable[[list[list[str]]], None]:
    """Row ``row`` (a number after the header, or the first of a phase) gets ``text``."""
    def edit(rows: list[list[str]]) -> None:
        rows[first_row(rows, row) if isinstance(row, str) else row][column] = text
    return edit


def set_episode(summary: Path, key: str, value: object) -> None:
    doc = json.loads(summary.read_text())
    doc["whiskers"]["tilted"]["episodes"][0][key] = value
    summary.write_text(json.dumps(doc))


def drop_summary_whisker(summary: Path) -> None:
    doc = json.loads(summary.read_text())
    del doc["whiskers"]["tilted"]
    summary.write_text(json.dumps(doc))


# (what to break, the file the message names, the problem it states); ``folder`` is a copy
# of the results, ``scene`` a copy of the scene folder.
CASES: list[tuple[str, Callable[[Path, Path], None], str, str]] = [
    ("a whisker without its csv", lambda folder, scene: (folder / "tilted.csv").unlink(),
     "tilted.csv", "missing: the scene's whisker 'tilted' has no results there"),
    ("another path: other times", lambda folder, scene: write_scene(scene, dt=0.02),
     "plain.csv", "row 2, column t: '0.01' is not the path's time 0.02 (the results of another"),
    ("a row less", lambda folder, scene: edit_csv(folder / "plain.csv", lambda rows: rows.pop()),
     "plain.csv", f"{SAMPLES - 1} rows, but the scene's path has {SAMPLES} samples"),
    ("an unknown phase", lambda folder, scene: edit_csv(folder / "plain.csv", set_cell(3, 1, "touch")),
     "plain.csv", "row 3, column phase: 'touch' is not a phase (none, tip, tangential, unresolved)"),
    ("not a number", lambda folder, scene: edit_csv(folder / "tilted.csv", set_cell(4, 4, "abc")),
     "tilted.csv", "row 4, column f0y: 'abc' is not a number"),
    ("a missing column", lambda folder, scene: edit_csv(folder / "plain.csv", drop_pz),
     "plain.csv", "missing column(s) pz (the columns are t,phase,s1,f0x"),
    ("a short row", lambda folder, scene: edit_csv(folder / "plain.csv", lambda rows: rows[5].pop()),
     "plain.csv", "row 5: expected 19 values, got 18"),
    ("a refined flag not 0 or 1", lambda folder, scene: edit_csv(folder / "plain.csv", set_cell(2, 13, "yes")),
     "plain.csv", "row 2, column refined: 'yes' is not 0 or 1"),
    ("an unknown second object", lambda folder, scene: edit_csv(folder / "plain.csv", set_cell(2, 18, "ghost")),
     "plain.csv", "row 2, column object2: 'ghost' is not an object of the scene"),
    ("a second contact not a number", lambda folder, scene: edit_csv(folder / "plain.csv", set_cell(3, 14, "x")),
     "plain.csv", "row 3, column s2: 'x' is not a number"),
    ("an unknown object", lambda folder, scene: edit_csv(folder / "plain.csv", set_cell("tip", 12, "mug")),
     "plain.csv", "column object: 'mug' is not an object of the scene (cup, ball)"),
    ("no wrench in contact", lambda folder, scene: edit_csv(folder / "plain.csv", set_cell("tip", 3, "")),
     "plain.csv", "column f0x: a tip sample needs a finite wrench, got ''"),
    ("another scene: the ball moved", lambda folder, scene: (scene / "scene.yaml").write_text(
        SCENE.replace("[-0.125, 0.0, 0.04]", "[-0.125, 0.0, 0.045]")),
     "summary.json", "the results of another scene: its scene_sha256 is not this scene's"),
    ("another scene: a stiffer rod", lambda folder, scene: (scene / "scene.yaml").write_text(
        SCENE.replace("ei_nm2: 2.0e-5", "ei_nm2: 3.0e-5")),
     "summary.json", "the results of another scene"),
    ("no summary", lambda folder, scene: (folder / "summary.json").unlink(),
     "summary.json", "No such file"),
    ("a summary without the whisker", lambda folder, scene: drop_summary_whisker(folder / "summary.json"),
     "summary.json", "whiskers.tilted.episodes: not as vibrissa simulate writes them (KeyError"),
    ("an episode begun otherwise", lambda folder, scene: set_episode(folder / "summary.json", "start", "jump"),
     "summary.json", "whiskers.tilted.episodes: not as vibrissa simulate writes them (ValueError: "
     "start 'jump' is not one of touch, landing, second-contact)"),
    ("an episode ended otherwise", lambda folder, scene: set_episode(folder / "summary.json", "end", 3),
     "summary.json", "(ValueError: end 3 is not one of detachment, snap-off"),
    ("no folder", lambda folder, scene: shutil.rmtree(folder),
     "", "not a folder (expected the -o DIR of vibrissa simulate)"),
]


@pytest.mark.parametrize(("break_it", "file", "problem"), [case[1:] for case in CASES],
                         ids=[case[0] for case in CASES])
def test_a_bad_folder_is_refused_at_start_naming_file_and_problem(
        simulated: Simulated, tmp_path: Path, break_it: Callable[[Path, Path], None], file: str,
        problem: str) -> None:
    folder, scene = tmp_path / "out", tmp_path / "scene"
    shutil.copytree(simulated.out, folder)
    scene.mkdir()
    write_scene(scene)
    break_it(folder, scene)
    with pytest.raises(SceneError) as read:
        read_results(folder, load_scene(scene / "scene.yaml"))
    named = str(folder / file) if file else str(folder)
    assert str(read.value).startswith(f"{named}: ") and problem in str(read.value), read.value
    with pytest.raises(ParamError) as start:
        load_params(WrenchSourceParams, overrides={
            "mode": "scene", "scene": str(scene / "scene.yaml"), "simulated": str(folder)})
    assert f"parameter 'simulated': {read.value}" in str(start.value)
