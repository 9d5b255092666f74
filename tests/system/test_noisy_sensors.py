"""Noisy sensors through the robot graph (launch/robot.yaml, real processes): with wrench noise
of 1e-3 of the scene's peak wrench, no point comes from a free rod and the points lie within
their predicted 3-sigma ellipsoids."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tests.system.test_robot_graph import SCENE, _run
from tests.system.test_system_pipeline import entries, node, set_param
from vibrissa.formats.scene_file import load_scene
from vibrissa.msgs import ContactPointArray
from vibrissa.scene import SamplePhase, simulate
from vibrissa.status import ContactStatus

CHI2_3DOF_3SIGMA = 14.156  # P(chi^2_3 <= 14.156) = 99.73 %, the 3-sigma ellipsoid


def test_noise_of_1e_3_gives_no_free_points_and_points_within_3_sigma(tmp_path: Path) -> None:
    scene = load_scene(SCENE)
    results = simulate(scene, workers=1)
    peak_f = float(max(np.linalg.norm(r.f0_n, axis=1).max() for r in results))
    peak_m = float(max(np.linalg.norm(r.m0_nm, axis=1).max() for r in results))
    launch = entries("robot.yaml")
    set_param(node(launch, "reconstructor"), "wait_for", ["/mapper", "/probe"])
    rc, arrays, eos, ended, counters = _run(
        tmp_path, launch, f"out:={tmp_path / 'out'}", f"scene:={SCENE}", "epoch:=0",
        f"noise_force:={1e-3 * peak_f!r}", f"noise_moment:={1e-3 * peak_m!r}")
    assert rc == 0, ended.text()
    truth = {(float(t), r.name): (phase, p) for r in results
             for t, phase, p in zip(r.t, r.phase, r.p_W_m, strict=True)}
    free = sum(int(np.sum(r.phase == SamplePhase.NONE)) for r in results)
    touching = sum(int(np.sum((r.phase == SamplePhase.TIP) | (r.phase == SamplePhase.TANGENTIAL)))
                   for r in results)
    assert free > 5000 and touching > 1000
    points = [(a.stamp, w, p, c, s) for a in arrays if isinstance(a, ContactPointArray)
              for w, p, c, s in zip(a.whisker_ids, a.point, a.covariance, a.status, strict=True)]
    phases = [truth[(stamp, w)][0] for stamp, w, *_ in points]
    # not one point from a free (or unresolved) rod: all come from true contacts
    assert all(phase in (SamplePhase.TIP, SamplePhase.TANGENTIAL) for phase in phases)
    assert counters["free"] >= free
    # most contacts give a point (the rest are within the noise of the touch and detachment)
    assert len(points) >= 0.8 * touching, (len(points), touching)
    d2 = []
    for stamp, w, point, cov, _ in points:
        error = point - truth[(stamp, w)][1]
        d2.append(error @ np.linalg.solve(cov, error))
    inside = np.mean(np.array(d2) <= CHI2_3DOF_3SIGMA)
    assert inside >= 0.99, inside
    assert counters["tip_within_noise"] == sum(
        int(s) & int(ContactStatus.TIP_WITHIN_NOISE) > 0 for *_, s in points)
