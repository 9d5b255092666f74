"""The mapper's steps without sockets: contact normals, the accumulator and its bounds, the
node's one conversion of messages to arrays, and the files of degenerate clouds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.nodes.test_nodes_logic import run_with_file_size_limit
from vibrissa.mapping import Accumulator, ContactBatch, contact_normals, split_lines
from vibrissa.msgs import ContactPointArray, EndOfStream
from vibrissa.nodes.mapper import MapperParams, contact_batch, receive, write_outputs
from vibrissa.surfaces import parse_surface


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
    acc = Accumulator(2)
    acc.add(ContactBatch("world", np.array([[0.0, 0, 1]]), np.array([[0.0, 0, 1]]), ["w"]))
    acc.end("/a")
    acc.end("/a")  # the same source twice
    assert not acc.done and acc.n_points == 1
    acc.end("/b")
    assert acc.done
    acc.add(ContactBatch("arm", np.zeros((0, 3)), np.zeros((0, 3)), [], seq=3))
    assert "arm" not in acc.frames  # a tick without contact adds no frame
    acc.add(ContactBatch("world", np.array([[0.0, 0, 2], [0, 0, 3]]),
                         np.array([[0.0, 0, 1], [0, 1, 0]]), ["u", "v"], seq=3))
    assert acc.n_points == 3
    points, forces, ids, _ = acc.frames["world"].ordered()
    assert ids == ["u", "v", "w"] and points[:, 2].tolist() == [2, 3, 1]
    np.testing.assert_array_equal(forces[1], [0, 1, 0])
    named = Accumulator(["/b"])
    named.end("/a")
    assert not named.done
    named.end("/b")
    assert named.done


def test_a_batch_of_rows_that_do_not_match_is_refused() -> None:
    with pytest.raises(ValueError, match=r"points_m must have shape \(2, 3\)"):
        ContactBatch("world", np.zeros((3, 3)), np.zeros((2, 3)), ["a", "b"])
    with pytest.raises(ValueError, match="covariances_m2"):
        ContactBatch("world", np.zeros((1, 3)), np.ones((1, 3)), ["a"],
                     covariances_m2=np.zeros((1, 3)))


def test_the_node_converts_a_contact_message_to_the_batch_of_its_rows() -> None:
    """The mapper's one conversion: every row with its whisker, the message's seq and the
    covariance; an end of stream ends its source."""
    array = ContactPointArray(stamp=0.0, seq=7, frame_id="arm", whisker_ids=["w", "v"],
                              point=[[0, 0, 1], [0, 1, 0]], s1=[0.5, 0.4], phase=[1, 2],
                              force=[[0, 0, 2], [0, 3, 0]], status=[0, 0],
                              covariance=[np.diag([1e-8, 2e-8, 3e-8]), np.eye(3) * 1e-8])
    batch = contact_batch(array)
    assert (batch.frame_id, list(batch.whisker_ids), batch.seq) == ("arm", ["w", "v"], 7)
    np.testing.assert_array_equal(batch.points_m, [[0, 0, 1], [0, 1, 0]])
    np.testing.assert_array_equal(batch.forces_n, [[0, 0, 2], [0, 3, 0]])
    assert batch.covariances_m2 is not None and batch.covariances_m2[1, 2, 2] == 1e-8
    acc = Accumulator(1)
    receive(acc, array)
    receive(acc, EndOfStream(stamp=0.0, source="/r", count=1))
    assert acc.n_points == 2 and acc.done


def _contact(i: int, point: list[float], frame_id: str = "world") -> ContactBatch:
    return ContactBatch(frame_id, np.array([point], dtype=float), np.array([[0.0, 0.0, 1.0]]),
                        ["w0"], seq=i)


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
    frame = report.as_dict()["frames"][0]
    assert frame["method"] == f"none: {why}"
    assert (frame["n_vertices"], frame["n_triangles"]) == (0, 0)
    assert sorted(frame["files"]) == ["cloud", "html", "png"]
    assert not (tmp_path / "mesh.ply").exists()
    assert (tmp_path / "cloud.ply").stat().st_size > 0
    assert f"method: none: {why}" in (tmp_path / "report.txt").read_text()
    cloud, mesh, unknown_mesh = messages[0].cloud, messages[0].mesh, messages[0].unknown_mesh
    assert len(cloud.points) == len(points) and len(mesh.vertices) == 0
    assert len(unknown_mesh.vertices) == 0


def test_frame_ids_that_collide_or_are_long_get_files_of_their_own(tmp_path: Path) -> None:
    frames = ["a/b", "a_b", "f" * 300, "ω"]
    acc = Accumulator(1)
    for frame in frames:
        for i in range(12):
            acc.add(_contact(i, [0.01 * i, 0.02 * (i % 3), 0.5 + 0.001 * i * i], frame))
    report, _ = write_outputs(acc, MapperParams(out_dir=str(tmp_path), plot=False), tmp_path)
    clouds = [frame.files["cloud"] for frame in report.frames]
    assert len(set(clouds)) == len(frames)
    assert all(len(Path(c).name) < 80 and Path(c).exists() for c in clouds)


def test_a_full_disk_leaves_no_half_written_map_file(tmp_path: Path) -> None:
    script = f"""
import numpy as np
from pathlib import Path
from vibrissa.mapping import Accumulator, ContactBatch
from vibrissa.nodes.mapper import MapperParams, write_outputs
acc = Accumulator(1)
for i in range(3000):
    acc.add(ContactBatch("world", np.array([[0.001 * (i % 60), 0.001 * (i // 60), 0.5 + 1e-4 * (i % 7)]]),
                         np.array([[0.0, 0.0, 1.0]]), ["w"], seq=i))
out = Path({str(tmp_path)!r})
try:
    write_outputs(acc, MapperParams(out_dir=str(out), plot=False), out)
except OSError as exc:
    print("error:", exc)
"""
    result = run_with_file_size_limit(script, 20_000)  # the cloud alone is ~100 kB
    assert "error:" in result.stdout, result.stdout + result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no file at all, half or whole


def test_ambiguous_points_are_counted_not_mapped() -> None:
    """A point Step 2 chose among several that fit its wrench (a pre-curved rod: AMBIGUOUS_
    CONTACT) is counted in ``dropped``, the others mapped; the message's statuses carry it."""
    from vibrissa.status import ContactStatus

    ambiguous = int(ContactStatus.AMBIGUOUS_CONTACT)
    msg = ContactPointArray(
        stamp=1.0, seq=0, frame_id="world", whisker_ids=["a", "a", "b"],
        point=[[0.0, 0.0, 0.1], [0.001, 0.0, 0.1], [0.0, 0.002, 0.1]],
        s1=[0.05, 0.05, 0.04], phase=[1, 1, 2], force=[[0.0, 0.0, 1.0]] * 3,
        status=[0, ambiguous, ambiguous | int(ContactStatus.TIP_WITHIN_NOISE)])
    acc = Accumulator()
    acc.add(contact_batch(msg))
    assert acc.n_points == 1
    assert dict(acc.dropped) == {"ambiguous_contact": 2}
