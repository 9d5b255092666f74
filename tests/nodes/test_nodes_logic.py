"""Node logic without sockets: the wrench source, normals, fit, accumulation, full disks."""

from __future__ import annotations

import resource
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from vibrissa.msgs import (
    ContactPhase,
    ContactPoint,
    ContactPointArray,
    ContactStatus,
    EndOfStream,
    WhiskerWrench,
    WhiskerWrenchArray,
)
from vibrissa.nodes.mapper import Accumulator, MapperParams, write_outputs
from vibrissa.nodes.reconstructor import ReconstructorParams
from vibrissa.nodes.surface_fit import contact_normals, split_lines
from vibrissa.nodes.wrench_source import WrenchSourceParams, tick_messages
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import SweepRun, Trail, simulate_sweeps
from vibrissa.ticks import sequential_ticks
from vibrissa.units import RodScale
from vibrissa.wire.bag import BagReader

UNIT_ROD = RodScale()


def sweep_wrenches(run: SweepRun, whisker_id: str, frame_id: str, rod: RodScale
                   ) -> Iterator[WhiskerWrench | WhiskerWrenchArray]:
    """The wrench source's one path, one whisker sweeping one sweep after the other."""
    return tick_messages(sequential_ticks(run, rod), [whisker_id] * len(run.trails), frame_id)


def test_sweep_wrenches_are_si_with_running_seq() -> None:
    surface = parse_surface("paraboloid:a=0.5,b=1,h=0.4")
    trails = [Trail(0.0, 0.1), Trail(0.3, 0.0)]
    sweeps = simulate_sweeps(surface, trails, 0.02)
    length, ei = 0.05, 2e-4
    msgs = list(sweep_wrenches(SweepRun(surface, trails, 0.02), "w7", "world",
                               RodScale(length, ei)))
    n0, n1 = sweeps[0].n_steps, sweeps[1].n_steps
    assert n0 > 3 and n1 > 3
    assert [m.seq for m in msgs] == list(range(n0 + n1))
    assert all(m.whisker_id == "w7" for m in msgs)
    last = msgs[n0 + 2]  # the third equilibrium of the second sweep
    np.testing.assert_array_equal(last.clamp_orientation, [0, 0, 0, 1])
    np.testing.assert_allclose(last.clamp_position, sweeps[1].p0[2] * length, rtol=1e-15)
    np.testing.assert_allclose(last.f0, sweeps[1].f0[2] * ei / length**2, rtol=1e-15)
    np.testing.assert_allclose(last.m0, sweeps[1].m0[2] * ei / length, rtol=1e-15)


@pytest.mark.parametrize("cls", [WrenchSourceParams, ReconstructorParams, MapperParams])
def test_params_give_the_rod_scale_and_refuse_a_rod_without_length(cls: Any) -> None:
    assert cls(rod_length_m=0.05).rod == RodScale(0.05, getattr(cls(), "rod_ei_nm2", 1.0))
    with pytest.raises(ValueError, match="length_m"):
        cls(rod_length_m=0.0)


def test_array_names_default_per_whisker_and_must_match_the_trails() -> None:
    params = WrenchSourceParams(y0=(0.1, 0.2, 0.3), array=True)
    assert params.array_whisker_ids == ["whisker0", "whisker1", "whisker2"]
    assert WrenchSourceParams(y0=(0.1,), whisker_ids=("left",)).array_whisker_ids == ["left"]
    with pytest.raises(ValueError, match=r"parameter 'whisker_ids' must be one name per y0 \(2\)"):
        WrenchSourceParams(y0=(0.1, 0.2), whisker_ids=("left",))


def _paraboloid_lines(mu: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Five contact lines on the demo paraboloid, sliding forces F = fn (n + mu t)."""
    surface = parse_surface("paraboloid:a=0.5,b=1,h=0.4")
    lines = []
    for y in (-0.4, -0.2, 0.0, 0.2, 0.4):
        x = np.linspace(0.8, -0.8, 400)  # the trail runs along -x
        lines.append(np.column_stack([x, np.full_like(x, y), 0.5 * x**2 + y**2 + 0.4]))
    points = np.vstack(lines)
    normal = surface.normal(points)
    # eq. 7: friction along the line towards the previous contact point (+x here)
    tangent = np.column_stack([np.ones(len(points)), np.zeros(len(points)), points[:, 0]])
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    forces = 2.0 * (normal + mu * tangent)
    return points, forces, normal


def test_contact_normals_recover_the_surface_normal_with_friction() -> None:
    points, forces, normal = _paraboloid_lines(mu=0.3)
    lines = split_lines(points)
    assert np.unique(lines).tolist() == [0, 1, 2, 3, 4]
    estimate = contact_normals(points, forces, lines)
    cos = np.einsum("ni,ni->n", estimate, normal)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 0.5  # F itself is 16.7 deg off


def test_accumulator_ends_on_count_or_names() -> None:
    point = ContactPoint(stamp=0.0, seq=0, whisker_id="w", frame_id="world", point=[0, 0, 1],
                         s1=0.5, phase=1, force=[0, 0, 1], status=0)
    acc = Accumulator(2)
    acc.add(point)
    acc.add(EndOfStream(stamp=0.0, source="/a", count=1))
    acc.add(EndOfStream(stamp=0.0, source="/a", count=1))  # the same source twice
    assert not acc.done and acc.n_points == 1
    acc.add(EndOfStream(stamp=0.0, source="/b", count=0))
    assert acc.done
    acc.add(ContactPointArray(stamp=0.0, seq=3, frame_id="arm", whisker_ids=[],
                              point=np.zeros((0, 3)), s1=[], phase=[], force=np.zeros((0, 3)),
                              status=[]))
    assert "arm" not in acc.frames  # a tick without contact adds no frame
    acc.add(ContactPointArray(stamp=0.0, seq=3, frame_id="world", whisker_ids=["u", "v"],
                              point=[[0, 0, 2], [0, 0, 3]], s1=[0.5, 0.6], phase=[1, 2],
                              force=[[0, 0, 1], [0, 1, 0]], status=[0, 0]))
    assert acc.n_points == 3
    points, forces, ids, _ = acc.frames["world"].ordered()
    assert ids == ["u", "v", "w"] and points[:, 2].tolist() == [2, 3, 1]
    np.testing.assert_array_equal(forces[1], [0, 1, 0])
    named = Accumulator(["/b"])
    named.add(EndOfStream(stamp=0.0, source="/a", count=1))
    assert not named.done
    named.add(EndOfStream(stamp=0.0, source="/b", count=1))
    assert named.done


def _contact(i: int, point: list[float], frame_id: str = "world") -> ContactPoint:
    return ContactPoint(stamp=0.0, seq=i, whisker_id="w0", frame_id=frame_id, point=point, s1=0.5,
                        phase=ContactPhase.TIP, force=[0.0, 0.0, 1.0], status=ContactStatus.OK)


@pytest.mark.parametrize(("points", "why"), [
    ([[0.0, 0.0, 0.5]], "1 point(s), a surface needs 4 or more"),
    ([[0.1 * i, 0.0, 0.5] for i in range(3)], "3 point(s), a surface needs 4 or more"),
    ([[0.01 * i, 0.02 * i, 0.5 - 0.01 * i] for i in range(100)],
     "all 100 points on one straight line"),
    ([[0.1, 0.1, 0.5]] * 50, "all 50 points at one place"),
])
def test_too_little_for_a_surface_is_a_report_line_and_the_cloud_is_written(
    tmp_path: Path, points: list[list[float]], why: str
) -> None:
    acc = Accumulator(1)
    for i, point in enumerate(points):
        acc.add(_contact(i, point))
    report, messages = write_outputs(acc, MapperParams(out_dir=str(tmp_path)), tmp_path)
    frame = report["frames"][0]
    assert frame["method"] == f"none: {why}"
    assert (frame["n_vertices"], frame["n_triangles"]) == (0, 0)
    assert sorted(frame["files"]) == ["cloud", "html", "png"]
    assert not (tmp_path / "mesh.ply").exists()
    assert (tmp_path / "cloud.ply").stat().st_size > 0
    assert f"method: none: {why}" in (tmp_path / "report.txt").read_text()
    cloud, mesh, _ = messages[0]
    assert len(cloud.points) == len(points) and len(mesh.vertices) == 0


def test_frame_ids_that_collide_or_are_long_get_files_of_their_own(tmp_path: Path) -> None:
    frames = ["a/b", "a_b", "f" * 300, "ω"]
    acc = Accumulator(1)
    for frame in frames:
        for i in range(12):
            acc.add(_contact(i, [0.01 * i, 0.02 * (i % 3), 0.5 + 0.001 * i * i], frame))
    report, _ = write_outputs(acc, MapperParams(out_dir=str(tmp_path), plot=False), tmp_path)
    clouds = [frame["files"]["cloud"] for frame in report["frames"]]
    assert len(set(clouds)) == len(frames)
    assert all(len(Path(c).name) < 80 and Path(c).exists() for c in clouds)


def run_with_file_size_limit(script: str, limit_bytes: int) -> subprocess.CompletedProcess[str]:
    """``script`` in a Python whose files cannot grow past ``limit_bytes``: writes beyond it
    fail as on a full disk (EFBIG instead of ENOSPC; SIGXFSZ is ignored)."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120, preexec_fn=limit)  # noqa: PLW1509 - the test's own child


def test_a_full_disk_leaves_no_half_written_map_file(tmp_path: Path) -> None:
    script = f"""
import numpy as np
from pathlib import Path
from vibrissa.msgs import ContactPhase, ContactPoint
from vibrissa.nodes.mapper import Accumulator, MapperParams, write_outputs
acc = Accumulator(1)
for i in range(3000):
    acc.add(ContactPoint(stamp=0.0, seq=i, whisker_id="w", frame_id="world",
                         point=[0.001 * (i % 60), 0.001 * (i // 60), 0.5 + 1e-4 * (i % 7)],
                         s1=0.5, phase=ContactPhase.TIP, force=[0.0, 0.0, 1.0], status=0))
out = Path({str(tmp_path)!r})
try:
    write_outputs(acc, MapperParams(out_dir=str(out), plot=False), out)
except OSError as exc:
    print("error:", exc)
"""
    result = run_with_file_size_limit(script, 20_000)  # the cloud alone is ~100 kB
    assert "error:" in result.stdout, result.stdout + result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no file at all, half or whole


def test_a_full_disk_stops_the_recorder_with_one_error_and_a_readable_bag(
    tmp_path: Path,
) -> None:
    bag = tmp_path / "rec.mcap"
    script = f"""
import numpy as np
from vibrissa.msgs import WhiskerWrench, encode
from vibrissa.nodes.recorder import RecorderParams, record
from vibrissa.wire.bag import BagReader
from vibrissa.wire.transport import Header, Received

class Endless:
    seq = 0
    def receive(self, timeout_s):
        self.seq += 1
        msg = WhiskerWrench(stamp=0.0, seq=self.seq, whisker_id="w", frame_id="w/clamp", pose_frame_id="world",
                            clamp_position=np.random.rand(3), clamp_orientation=[0, 0, 0, 1],
                            f0=np.random.rand(3), m0=np.random.rand(3))
        return Received("/w/wrench", msg, encode(msg), Header(1, self.seq), 0.0)
    def totals(self):
        return {{"lost": 0, "rejected": 0}}

try:
    record(RecorderParams(output={str(bag)!r}, chunk_size=4096), Endless())
except OSError as exc:
    print("error:", exc.errno, "chained:", exc.__context__ is not None)
"""
    result = run_with_file_size_limit(script, 200_000)
    # the write's own error, not a second one from closing the bag on the same full disk
    assert result.stdout.strip() == "error: 27 chained: False", result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    got = list(BagReader(bag))
    assert len(got) > 100 and all(r.topic == "/w/wrench" for r in got)
