"""The live map (`vibrissa.mapping.LiveMap`): updates as points arrive refit only what changed,
objects that merge or split are fitted again, and the final map is the single fit's, bit for
bit; the conditioned GP (`gp_surface.extended`) is the regression on the union of the active
points."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vibrissa.mapping import (
    Accumulator,
    ContactBatch,
    FrameCloud,
    FrameMap,
    LiveMap,
    LiveSettings,
    MapSettings,
    TrueObject,
    fit_frame,
    gp_surface,
)
from vibrissa.surfaces import parse_surface

RADIUS_M = 0.02
CENTRES_M = (np.array([0.0, 0.0, 0.05]), np.array([0.2, 0.0, 0.05]))
BALLS = tuple(TrueObject(f"ball{k}", parse_surface(f"sphere:r={RADIUS_M},cx={c[0]},cz={c[2]}"))
              for k, c in enumerate(CENTRES_M))
SETTINGS = MapSettings(cells=32)
DOUBLE = LiveSettings(single=False)
"""Updates meshed as `fit_frame` meshes: a full fit at the settings' grid is its fit, bit for bit."""


def ball_line(centre: np.ndarray, polar: float, whisker: str, mu: float = 0.3
              ) -> ContactBatch:
    """One whisker's contact line on a ball (80 points, in the order touched) with the contact
    forces F = f_n (n + mu t), t towards the previous contact (eq. 7)."""
    azimuth = np.linspace(-0.8, 0.8, 80)
    n = np.column_stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth),
                         np.full_like(azimuth, np.cos(polar))])
    p = centre + RADIUS_M * n
    t = -np.gradient(p, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return ContactBatch("world", p, 0.02 * (n + mu * t), [whisker] * len(p))


def plane_line(y: float, x: tuple[float, float], count: int, whisker: str) -> ContactBatch:
    """A whisker's contact line along x on the plane z = 0, pushed along +z."""
    p = np.column_stack([np.linspace(*x, count), np.full(count, y), np.zeros(count)])
    return ContactBatch("world", p, np.tile([0.0, 0.0, 1.0], (count, 1)), [whisker] * count)


def assert_same_map(a: FrameMap, b: FrameMap) -> None:
    """Two maps with the same bits: meshes, stds, labels, report and next sweeps."""
    for name in ("vertices", "triangles", "std", "labels", "points", "normals"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.result == b.result
    assert [[p.offset_m for p in obj] for obj in a.proposals] == [
        [p.offset_m for p in obj] for obj in b.proposals]


@pytest.mark.slow
def test_the_final_map_of_a_stream_is_the_single_fit_bit_for_bit() -> None:
    """Two balls touched line by line, in turns, with an update after each line: the updates
    condition the grown objects; the final map is `fit_frame`'s on the same points."""
    acc, live = Accumulator(), LiveMap()
    for k, polar in enumerate((1.0, 1.2, 1.4, 1.6)):
        for b, centre in enumerate(CENTRES_M):
            acc.add(ball_line(centre, polar, f"b{b}w{k}"))
            live.update("world", acc.frames["world"], SETTINGS, BALLS)
    assert live.fits["conditioned"] >= 2  # the third and fourth lines of each ball at least
    final = live.final("world", acc.frames["world"], SETTINGS, BALLS)
    single = fit_frame("world", acc.frames["world"], SETTINGS, BALLS)
    assert [obj.name for obj in single.result.objects] == ["ball0", "ball1"]
    assert_same_map(final, single)
    fits = live.fits.copy()
    assert_same_map(live.final("world", acc.frames["world"], SETTINGS, BALLS), single)
    assert live.fits["full"] == fits["full"]  # a second final keeps every fit


@pytest.mark.slow
def test_only_the_object_that_received_points_is_refitted() -> None:
    """A line on one ball leaves the other's surface as it was (the same object) and conditions
    the touched one's GP on the new points, without clustering the frame again; its surface is
    then within a few of its position stds of the single fit's."""
    acc, live = Accumulator(), LiveMap()
    for k, polar in enumerate((1.0, 1.2, 1.4, 1.6)):
        for b, centre in enumerate(CENTRES_M):
            acc.add(ball_line(centre, polar, f"b{b}w{k}"))
    before = live.update("world", acc.frames["world"], SETTINGS, BALLS)
    fits = live.fits.copy()
    acc.add(ball_line(CENTRES_M[1], 1.8, "b1w4"))
    after = live.update("world", acc.frames["world"], SETTINGS, BALLS)
    assert live.fits - fits == {"kept": 1, "conditioned": 1, "joined": 1}
    assert after.surfaces[0] is before.surfaces[0]
    assert all(a is b for a, b in zip(after.proposals[0], before.proposals[0], strict=True))
    assert after.result.objects[1].n_points == 400
    grown, single = after.surfaces[1].gp, fit_frame("world", acc.frames["world"], SETTINGS,
                                                    BALLS).surfaces[1]
    assert grown is not None and single.gp is not None and single.mesh is not None
    assert len(grown.active) > len(before.surfaces[1].gp.active)  # type: ignore[union-attr]
    # where the single fit is known, the conditioned mean's zero set is within 3 stds of it
    # (two estimates from one cloud with other active points: measured 1.0 of the larger std)
    known = single.mesh.part(known=True)
    f, g = grown.evaluate(known[0])
    offset = np.abs(f) / np.linalg.norm(g, axis=1)
    assert offset.max() < 3 * np.maximum(known[2], grown.position_std(known[0])).max()


def test_clusters_joined_by_new_points_are_one_object_fitted_again() -> None:
    """Two patches of a plane farther apart than the DBSCAN radius are two objects; lines
    between them make them one, fitted in full as the single fit does."""
    settings = MapSettings(cells=32, cluster_eps_m=0.015, join_convex=False, proposals=0)
    acc, live = Accumulator(), LiveMap(DOUBLE)
    for y in (0.0, 0.01, 0.02, 0.06, 0.07, 0.08):
        acc.add(plane_line(y, (0.0, 0.1), 101, f"w{y}"))
    assert len(live.update("world", acc.frames["world"], settings).surfaces) == 2
    fits = live.fits.copy()
    for y in (0.03, 0.04, 0.05):
        acc.add(plane_line(y, (0.0, 0.1), 101, f"w{y}"))
    merged = live.update("world", acc.frames["world"], settings)
    assert live.fits - fits == {"clustered": 1, "full": 1}
    assert_same_map(merged, fit_frame("world", acc.frames["world"], settings))
    assert len(merged.surfaces) == 1


def test_an_object_split_by_new_points_is_two_objects_fitted_again() -> None:
    """Two long lines 0.3 m apart are one object (the radius from the data: half a line's
    extent, 0.5 m); many short lines near each shrink the radius below their gap, and the
    frame clustered again (their points outgrow ``refit_growth``) is two objects."""
    settings = MapSettings(cells=32, join_convex=False, proposals=0)
    acc, live = Accumulator(), LiveMap(DOUBLE)
    for y in (0.0, 0.3):
        acc.add(plane_line(y, (0.0, 1.0), 1001, f"long{y}"))
    assert len(live.update("world", acc.frames["world"], settings).surfaces) == 1
    fits = live.fits.copy()
    for k in range(10):
        for y in (0.01 + 0.01 * k, 0.29 - 0.01 * k):
            acc.add(plane_line(y, (0.5, 0.524), 121, f"short{y:.2f}"))
    split = live.update("world", acc.frames["world"], settings)
    assert live.fits - fits == {"clustered": 1, "full": 2}
    assert_same_map(split, fit_frame("world", acc.frames["world"], settings))
    assert len(split.surfaces) == 2


def refactored(surface: gp_surface.GPSurface, points: np.ndarray, normals: np.ndarray
               ) -> gp_surface.GPSurface:
    """The regression of ``surface`` on its observations and ``points`` (K, 3) with unit
    ``normals`` at the least point std, its hyperparameters kept, from one new Cholesky factor
    of all of them in `_design`'s order: the formulation `gp_surface.extended` avoids."""
    u = np.concatenate([surface._u, (points - surface.center) / surface.scale])
    n = np.concatenate([surface._n, normals / np.linalg.norm(normals, axis=1, keepdims=True)])
    stds = np.concatenate([surface._point_std, np.full(len(points), surface.point_std)])
    sigma = surface.sigma
    solution = gp_surface._solve(
        sigma * sigma * gp_surface._prior(u, surface.length_scale)
        + gp_surface._noise(n, stds, surface.normal_std), gp_surface._design(u),
        surface.quadric_std, gp_surface._targets(n))
    return replace(surface, _point_std=stds, _u=u, _n=n, _solution=solution,
                   _alpha_se=sigma * sigma * solution.alpha, _order=None)


def test_extending_a_fit_is_the_regression_on_the_union_of_its_active_points() -> None:
    """`gp_surface.extended` (the Cholesky factor grown by blocks, twice) against `refactored`
    (one factor of all the observations, in `_design`'s order): the same mean, gradient and
    std to rounding."""
    lines = [ball_line(CENTRES_M[0], polar, "w") for polar in (1.0, 1.2, 1.4, 1.6, 1.8)]
    points = np.vstack([line.points_m for line in lines])
    normals = (points - CENTRES_M[0]) / RADIUS_M
    fit = gp_surface.fit(points[:240], normals[:240])
    once = gp_surface.extended(fit, points[240:320], normals[240:320], 12)
    twice = gp_surface.extended(once, points[320:], normals[320:], 12)
    taken = np.concatenate([twice.active[len(fit.active):]]) - 240
    assert len(taken) == len(twice._u) - len(fit._u) and len(taken) >= 20
    direct = refactored(fit, points[240:][taken], normals[240:][taken])
    q = CENTRES_M[0] + np.random.default_rng(0).uniform(-2, 2, (300, 3)) * RADIUS_M
    for a, b in zip(twice.evaluate(q), direct.evaluate(q), strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.abs(b).max())
    np.testing.assert_allclose(twice.std(q), direct.std(q), rtol=1e-7)
    with pytest.raises(ValueError, match="count"):
        gp_surface.extended(fit, points[240:], normals[240:], 0)


@pytest.mark.parametrize(("kwargs", "name"), [({"refit_growth": 0.0}, "refit_growth"),
                                              ({"cells": 4}, "cells")])
def test_live_settings_refuse_values_out_of_range(kwargs: dict[str, float], name: str) -> None:
    with pytest.raises(ValueError, match=name):
        LiveSettings(**kwargs)  # type: ignore[arg-type]


def test_an_update_without_new_points_keeps_everything() -> None:
    cloud = FrameCloud()
    cloud.add(ball_line(CENTRES_M[0], 1.0, "w0"), None, np.full((80, 3, 3), np.nan))
    cloud.add(ball_line(CENTRES_M[0], 1.3, "w1"), None, np.full((80, 3, 3), np.nan))
    live = LiveMap()
    first = live.update("world", cloud, SETTINGS)
    again = live.update("world", cloud, SETTINGS)  # the same cloud, not grown: the same map
    assert live.fits == {"clustered": 1, "full": 1, "unchanged": 1} and again is first
    copy = FrameCloud()  # another cloud of the same points: its objects joined, each kept
    for k in range(2):
        copy.add(ball_line(CENTRES_M[0], (1.0, 1.3)[k], f"w{k}"), None,
                 np.full((80, 3, 3), np.nan))
    other = live.update("world", copy, SETTINGS)
    assert live.fits == {"clustered": 1, "full": 1, "unchanged": 1, "joined": 1, "kept": 1}
    assert other.surfaces[0] is first.surfaces[0]
    assert live.final("world", copy, SETTINGS) is not other  # joined: not the single fit's
    assert live.fits["clustered"] == 2


def test_points_gone_since_the_last_update_mean_a_new_clustering_and_fit() -> None:
    """A cloud that lost points (merged away upstream) is not the last one grown: the frame is
    clustered again and the object fitted in full, as the single fit does."""
    lines = [ball_line(CENTRES_M[0], polar, f"w{k}") for k, polar in enumerate((1.0, 1.3, 1.6))]
    live = LiveMap(DOUBLE)
    for kept in (lines, lines[1:]):
        cloud = FrameCloud()
        for line in kept:
            cloud.add(line, None, np.full((80, 3, 3), np.nan))
        fits = live.fits.copy()
        fewer = live.update("world", cloud, SETTINGS)
    assert live.fits - fits == {"clustered": 1, "full": 1}
    assert_same_map(fewer, fit_frame("world", cloud, SETTINGS))


def test_an_update_in_single_precision_has_the_known_part_of_the_double_one() -> None:
    """An update's vertex stds solved in single precision (the default): the same mesh and
    known part as `fit_frame`'s at the same grid, each std within 1e-2 of the prior std (a few
    1e-3 measured); the final map is the single fit's, in double."""
    acc, live = Accumulator(), LiveMap()
    for k, polar in enumerate((1.0, 1.2, 1.4)):
        acc.add(ball_line(CENTRES_M[0], polar, f"w{k}"))
    update = live.update("world", acc.frames["world"], SETTINGS, BALLS)
    single = fit_frame("world", acc.frames["world"], SETTINGS, BALLS)
    mesh, exact = update.surfaces[0].mesh, single.surfaces[0].mesh
    gp = single.surfaces[0].gp
    assert mesh is not None and exact is not None and gp is not None
    np.testing.assert_array_equal(mesh.vertices, exact.vertices)
    np.testing.assert_array_equal(mesh.known, exact.known)
    assert np.abs(mesh.std - exact.std).max() <= 1e-2 * gp.sigma * gp.scale
    assert not np.array_equal(mesh.std, exact.std)  # the solve was single
    assert_same_map(live.final("world", acc.frames["world"], SETTINGS, BALLS), single)


def test_next_sweeps_left_out_of_an_update_are_those_it_would_have_proposed() -> None:
    """``propose=False``: the objects fitted in full have no next sweeps in the update's map
    (nor in its report); `LiveMap.propose` gives them, the same as an update that proposed;
    a conditioned object keeps those of its full fit."""
    acc = Accumulator()
    for b, centre in enumerate(CENTRES_M):
        for k, polar in enumerate((1.0, 1.2, 1.4)):
            acc.add(ball_line(centre, polar, f"b{b}w{k}"))
    proposing, leaving = LiveMap(), LiveMap()
    full = proposing.update("world", acc.frames["world"], SETTINGS, BALLS)
    left = leaving.update("world", acc.frames["world"], SETTINGS, BALLS, propose=False)
    assert [len(p) for p in full.proposals] == [3, 3]
    assert left.proposals == [[], []]
    assert all(not obj.next_sweeps for obj in left.result.objects)
    proposed = leaving.propose("world")
    assert_same_map(proposed, full)
    assert leaving.propose("world") is proposed  # nothing left out any more
    acc.add(ball_line(CENTRES_M[1], 1.6, "b1w3"))  # ball1 grows, conditioned
    grown = leaving.update("world", acc.frames["world"], SETTINGS, BALLS, propose=False)
    assert leaving.fits["conditioned"] == 1
    assert grown.proposals[1] == proposed.proposals[1]
    assert leaving.propose("world") is grown
