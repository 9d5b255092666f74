"""The whiskers of a scene solved together: every step of the whiskers in contact is one call
of the compiled kernels, rows of different objects (each whisker's own L), and each whisker's
results are the same bits as when it is solved alone, in one process or spread over two."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import vibrissa.sweep
from vibrissa.equilibrium import MODE_TIP, Q_WIDTH, newton_rows
from vibrissa.frames import Transform
from vibrissa.rods import RodShape
from vibrissa.scene import (
    SamplePhase,
    Scene,
    SceneObject,
    Whisker,
    WhiskerResult,
    robot_path,
    simulate,
    simulate_whisker,
)
from vibrissa.surfaces import parse_surface

FIELDS = ("t", "phase", "s1_m", "f0_n", "m0_nm", "p_W_m", "object", "second_s_m", "second_W_m",
          "second_object")

pytestmark = pytest.mark.slow  # batched against alone, scene by scene: make test runs them, make check not


def random_scene(rng: np.random.Generator) -> Scene:
    """1-3 posed spheres, ellipsoids and paraboloids; 2-5 whiskers of their own L (30-80 mm),
    stiffness and tilted mount; a line, an arc or a turn on the spot, half of them with a
    pause; mu from 0 to 0.6."""
    L = 0.05
    objects = []
    for i in range(rng.integers(1, 4)):
        kind = rng.choice(["sphere", "ellipsoid", "paraboloid"])
        rotation = (Rotation.random(random_state=rng) if kind != "paraboloid"
                    else Rotation.from_euler("xyz", rng.uniform(-0.3, 0.3, 3)))
        X = Transform(rotation, [rng.uniform(-1.5, 1.5) * L, rng.uniform(-0.3, 0.3) * L,
                                 rng.uniform(0.5, 0.9) * L])
        if kind == "sphere":
            sizes: dict[str, object] = {"radius_m": rng.uniform(0.15, 0.4) * L}
        elif kind == "ellipsoid":
            sizes = {"semi_axes_m": list(rng.uniform(0.15, 0.4, 3) * L)}
        else:
            X = Transform(X.rotation, [X.translation[0], X.translation[1], rng.uniform(0.3, 0.6) * L])
            sizes = {"a_per_m": rng.uniform(0.3, 1.5) / L, "b_per_m": rng.uniform(0.3, 1.5) / L,
                     "h_m": 0.0}
        objects.append(SceneObject(f"o{i}", str(kind), sizes, X))
    whiskers = []
    for j in range(rng.integers(2, 6)):
        length = rng.uniform(0.03, 0.08)
        mount = Transform(Rotation.from_euler("xy", rng.uniform(-0.35, 0.35, 2)),
                          rng.uniform(-0.2, 0.2, 3) * L)
        whiskers.append(Whisker(f"w{j}", length, rng.uniform(1e-5, 5e-5), mount))
    n = int(rng.integers(300, 700))
    motion = rng.choice(["line", "arc", "spin"])
    s = np.linspace(0, 1, n)
    if motion == "line":
        p = np.column_stack([(2.5 - 5 * s) * L, np.full(n, rng.uniform(-0.3, 0.3) * L), np.zeros(n)])
        yaw = np.zeros(n)
    elif motion == "arc":
        R = rng.uniform(1.5, 4) * L
        th = (s - 0.5) * 5 * L / R
        p = np.column_stack([-R * np.sin(th), R * (1 - np.cos(th)) + rng.uniform(-0.3, 0.3) * L,
                             np.zeros(n)])
        yaw = -th
    else:
        p, yaw = np.zeros((n, 3)), s * 2 * np.pi
    if rng.uniform() < 0.5:
        k = n // 2
        p[k : k + 20], yaw[k : k + 20] = p[k], yaw[k]
    path = robot_path(s * 5, p, Rotation.from_euler("z", yaw[:, None]).as_quat())
    return Scene(float(rng.uniform(0, 0.6)), tuple(objects), tuple(whiskers), path)


def assert_same_bits(a: WhiskerResult, b: WhiskerResult) -> None:
    assert a.name == b.name
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.episodes == b.episodes


SEEDS = [1001, 1004]  # contacts of several whiskers at once, snap-offs, unresolved samples


@pytest.fixture(scope="module", params=SEEDS)
def scene(request: pytest.FixtureRequest) -> Scene:
    return random_scene(np.random.default_rng(request.param))


@pytest.fixture(scope="module")
def alone(scene: Scene) -> list[WhiskerResult]:
    return [simulate_whisker(scene, whisker) for whisker in scene.whiskers]


def test_whiskers_solved_together_are_the_bits_of_each_alone(
        scene: Scene, alone: list[WhiskerResult], monkeypatch: pytest.MonkeyPatch) -> None:
    objects_per_call: list[int] = []

    def counting(*args):  # type: ignore[no-untyped-def]
        Q = args[7]  # (n, 3, 3): one per row's object, scaled to its whisker's L
        objects_per_call.append(len(np.unique(Q.reshape(len(Q), -1), axis=0)))
        return newton_rows(*args)

    monkeypatch.setattr(vibrissa.sweep, "newton_rows", counting)
    together = simulate(scene, workers=1)
    assert max(objects_per_call) >= 2, "whiskers in contact at once share the kernel calls"
    assert {e.end for r in together for e in r.episodes} >= {"detachment", "snap-off"}
    # samples past another object: unresolved, or with both contacts
    assert any((r.phase == SamplePhase.UNRESOLVED).any() or (r.second_object >= 0).any()
               for r in together)
    for a, b in zip(together, alone, strict=True):
        assert_same_bits(a, b)


def test_two_workers_give_the_same_bits_in_the_scene_order(
        scene: Scene, alone: list[WhiskerResult]) -> None:
    done: list[tuple[int, int]] = []
    results = simulate(scene, workers=2, progress=lambda *d: done.append(d))
    assert [r.name for r in results] == [w.name for w in scene.whiskers]
    total = len(scene.whiskers)
    assert done[0] == (0, total) and done[-1] == (total, total)
    for a, b in zip(results, alone, strict=True):
        assert_same_bits(a, b)


def test_kernel_rows_of_different_objects_are_the_bits_of_each_row_alone() -> None:
    """Rows of different objects and rods (two uniform rods, the elastica; a tapered pre-curved
    one, the Kirchhoff rod) solved in one call: each row's bits are its own alone."""
    surfaces = [parse_surface("paraboloid:a=0.5,b=1,h=0.4"),
                parse_surface("sphere:r=0.3,cx=0.1,cy=0.05,cz=0.8,roll=0.3"),
                parse_surface("sphere:r=0.3,cx=0.35,cy=0.05,cz=0.6")]
    rows = 3
    q0 = np.zeros((rows, Q_WIDTH))
    q0[0, :4] = 0.1, 0.02, -0.01, -0.02
    q0[1, :4] = -0.2, 0.05, 0.01, -0.04
    q0[2] = 0.9, -0.05, 0.0, 0.01, 0.0, -0.04, 0.0
    params = np.array([RodShape().params, RodShape().params,
                       RodShape(taper_ratio=0.6, precurvature=1.0).params])
    p_WC = np.array([[0.0, 0.2, 0.0], [0.05, 0.1, 0.02], [0.0, 0.05, 0.0]])
    R_WC = np.repeat(np.eye(3)[None], rows, axis=0)
    mu = np.array([0.3, 0.5, 0.3])
    anchor = np.array([[0.1, 0.2, 0.5], [0.1, 0.1, 0.6], [0.06, 0.05, 0.6]])
    mode = np.full(rows, MODE_TIP, dtype=np.int64)
    locked = np.zeros(rows, dtype=bool)
    objects = [np.concatenate(parts) for parts in zip(*(s.kernel_arrays for s in surfaces),
                                                      strict=True)]
    q, state = newton_rows(q0, p_WC, R_WC, mu, anchor, mode, locked, *objects, params)
    assert state[2, 25] == 1.0  # the Kirchhoff row converged (`STATE_WIDTH`)
    for r, surface in enumerate(surfaces):
        one = slice(r, r + 1)
        q_r, state_r = newton_rows(q0[one], p_WC[one], R_WC[one], mu[one], anchor[one],
                                   mode[one], locked[one], *surface.kernel_arrays, params[one])
        np.testing.assert_array_equal(q[one], q_r)
        np.testing.assert_array_equal(state[one], state_r)
