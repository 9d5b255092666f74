"""The map from a plain script, through `vibrissa.mapping` alone (no node, no messages, no
files): contact lines on a ball with friction, mapped and measured against the ball."""

from __future__ import annotations

import numpy as np

from vibrissa.mapping import Accumulator, ContactBatch, MapSettings, TrueObject, fit_frame, map_cloud
from vibrissa.surfaces import parse_surface

RADIUS_M = 0.02
CENTRE_M = np.array([0.0, 0.0, 0.05])
BALL = TrueObject("ball", parse_surface(f"sphere:r={RADIUS_M},cz={CENTRE_M[2]}"))


def ball_lines(mu: float = 0.3) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Four whiskers' contact lines on the ball (80 points each, in the order touched) and the
    contact forces F = f_n (n + mu t), t towards the previous contact (eq. 7)."""
    points, forces, whiskers = [], [], []
    for k, polar in enumerate((1.0, 1.2, 1.4, 1.6)):
        azimuth = np.linspace(-0.8, 0.8, 80)
        n = np.column_stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth),
                             np.full_like(azimuth, np.cos(polar))])
        p = CENTRE_M + RADIUS_M * n
        t = -np.gradient(p, axis=0)
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        points.append(p)
        forces.append(0.02 * (n + mu * t))
        whiskers += [f"w{k}"] * len(azimuth)
    return np.vstack(points), np.vstack(forces), whiskers


def test_a_script_maps_a_cloud_and_its_surface_lies_on_the_true_object() -> None:
    points, forces, whiskers = ball_lines()
    settings = MapSettings()
    frame = map_cloud(points, forces, whiskers, settings, truth=[BALL])
    [obj] = frame.result.objects
    assert (obj.name, obj.n_points, obj.true_object) == ("ball", 320, "ball")
    assert frame.result.clustering.method == "dbscan" and frame.result.noise_points == 0
    # the normals come from the forces with the friction along the line removed: exact inside
    # a line (a central chord of an evenly sampled circle is along its tangent), off by half
    # the angle of the one-sided chord at its ends (0.02 rad of azimuth apart: 0.01 rad)
    cos = np.einsum("ni,ni->n", frame.normals, (points - CENTRE_M) / RADIUS_M).reshape(4, 80)
    assert cos[:, 1:-1].min() > np.cos(1e-6) and cos.min() > np.cos(0.011)
    assert obj.cloud_to_surface_max is not None and obj.cloud_to_surface_max < 1e-15
    # Tolerance of the mesh: marching cubes places a vertex by interpolating f linearly along a
    # grid edge of length h; for f near the signed distance to a ball of radius R that is off by
    # at most h^2 / (8 R) (the bound |f''| h^2 / 8 of linear interpolation, |f''| <= 1/R), and
    # the mean of the surface is off by less than its std where it is known (<= max_std_m).
    lo, hi = points.min(axis=0), points.max(axis=0)
    box = (hi - lo).max() + 2 * settings.margin * np.linalg.norm(hi - lo)
    h = box / settings.cells
    tolerance = h**2 / (8 * RADIUS_M) + obj.max_std_m
    assert obj.n_triangles > 1000 and len(frame.vertices) == obj.n_vertices
    distance = BALL.distance(frame.vertices)
    assert distance.max() == obj.mesh_to_surface_max < tolerance  # measured 2.7 um < 12 um
    larger = TrueObject("larger", parse_surface(f"sphere:r={RADIUS_M * 1.001},cz={CENTRE_M[2]}"))
    assert larger.distance(frame.vertices).max() > tolerance  # 20 um off would fail
    assert np.all(frame.std <= obj.max_std_m)
    assert len(frame.proposals[0]) == settings.proposals == len(obj.next_sweeps)
    assert frame.result.as_dict()["objects"][0]["mesh_to_surface_max"] == obj.mesh_to_surface_max


def test_a_stream_of_batches_maps_as_the_whole_cloud_bit_for_bit() -> None:
    """Points arriving as batches (per whisker, out of order between whiskers) through the
    accumulator give the map of the same cloud at once."""
    points, forces, whiskers = ball_lines()
    acc = Accumulator(expected=1)
    for start in range(0, len(points), 20)[::-1]:
        rows = slice(start, start + 20)
        acc.add(ContactBatch("world", points[rows], forces[rows], whiskers[rows], seq=start))
    acc.end("script")
    assert acc.done and acc.n_points == 320
    streamed = fit_frame("world", acc.frames["world"], MapSettings(proposals=0), [BALL])
    whole = map_cloud(points, forces, whiskers, MapSettings(proposals=0), [BALL])
    np.testing.assert_array_equal(streamed.vertices, whole.vertices)
    assert streamed.result == whole.result
