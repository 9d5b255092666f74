"""Step 2 row by row: a sample gives the same bits alone as in any batch; every case is flagged."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vibrissa.elastica import planar_contact, planar_contact_scalar
from vibrissa.reconstruct import (
    TALLY,
    Reconstruction,
    ReconstructionSI,
    reconstruct,
    reconstruct_si,
)
from vibrissa.status import NO_CONTACT, ContactStatus
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import simulate_sweep
from vibrissa.units import RodScale

FIELDS = ("point", "s1", "phase", "psi", "force", "status")


def _random_wrenches(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Wrenches over four decades of load, with every degenerate case planted in between."""
    rng = np.random.default_rng(seed)
    p0 = rng.uniform(-1, 1, (n, 3))
    f0 = rng.normal(size=(n, 3)) * rng.choice([1e-3, 1.0, 10.0, 100.0], (n, 1))
    m0 = rng.normal(size=(n, 3)) * rng.choice([1e-3, 1.0, 10.0], (n, 1))
    # every other row a single contact's wrench (m0z = 0, f0 in the plane normal to m0); the
    # rest is what no single contact gives (MULTI_CONTACT)
    m0[::2, 2] = 0.0
    m0_h = m0[::2]
    f0[::2] -= m0_h * (np.sum(f0[::2] * m0_h, axis=1) / np.sum(m0_h * m0_h, axis=1))[:, None]
    f0[0::40] = 0.0  # no force
    m0[1::40] = 0.0  # straight rod: the plane follows the force
    m0[2::40, :2] = 0.0  # twist only
    f0[3::40, :2] = 0.0  # axial load ...
    f0[3::40, 2] = np.abs(f0[3::40, 2])  # ... pushing the rod (f0z > 0: force on rod along -z)
    m0[3::40] = 0.0
    f0[4::40] = m0[4::40] = 0.0  # nothing at all
    f0[5::40, 1] = np.nan
    m0[6::40, 0] = np.inf
    p0[7::40, 2] = -np.inf
    f0[8::40, 2] = np.inf
    m0[9::40, 2] = np.nan  # twist component: not used, still non-finite input
    f0[10::40, 0] = -0.0
    return p0, f0, m0


def _assert_same(one: Reconstruction, many: Reconstruction, i: int) -> None:
    for name in FIELDS:
        a, b = getattr(one, name), getattr(many, name)[i : i + 1]
        assert a.shape == b.shape and a.dtype == b.dtype, name
        np.testing.assert_array_equal(a, b, err_msg=name)  # NaN where NaN, else the same bits


@pytest.mark.parametrize("seed", [0, 1])
def test_single_sample_equals_array_path(seed):
    p0, f0, m0 = _random_wrenches(4000, seed)
    many = reconstruct(p0, f0, m0)
    flags = set(many.status.tolist())
    # every outcome is exercised
    assert {0, 1, 2, 4, 16, 64} <= flags and any(s & ContactStatus.NON_FINITE_INPUT for s in flags)
    for i in range(len(p0)):
        _assert_same(reconstruct(p0[i], f0[i], m0[i]), many, i)


def test_single_sample_with_clamp_orientation():
    p0, f0, m0 = _random_wrenches(400, 2)
    angle, axis = 0.9, np.array([0.3, -1.0, 0.4]) / np.linalg.norm([0.3, -1.0, 0.4])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
    many = reconstruct(p0, f0, m0, R)
    for i in range(len(p0)):
        _assert_same(reconstruct(p0[i], f0[i], m0[i], R), many, i)
        _assert_same(reconstruct(p0[i], f0[i], m0[i], R[None]), many, i)


def test_single_sample_edge_cases_and_plain_lists():
    cases = {
        "no force": ([0, 0, 0], [0, 0, 0], [0.3, 0.1, 0], ContactStatus.NO_FORCE),
        "no moment": ([0, 0, 0], [0.2, 0.1, 0.5], [0, 0, 0], ContactStatus.CONTACT_BEYOND_ROD),
        "never zero": ([0, 0, 0], [0, 0, -1e-3], [3, 0, 0], ContactStatus.CURVATURE_NEVER_VANISHES),
        "beyond rod": ([0, 0, 0], [-0.1, 0, 0], [0, -0.3, 0], ContactStatus.CONTACT_BEYOND_ROD),
        "tangential": ([0, 0, 0], [0.1, 0, 0], [0, 0.05, 0], ContactStatus.OK),
        "axial": ([1, 2, 3], [0, 0, 2.0], [0, 0, 0], ContactStatus.AXIAL_LOAD),
        "nan p0": ([np.nan, 0, 0], [0.1, 0, 0], [0, 0.05, 0], ContactStatus.NON_FINITE_INPUT),
        "inf f0": ([0, 0, 0], [np.inf, 0, 0], [0, 0.05, 0], ContactStatus.NON_FINITE_INPUT),
    }
    for name, (p0, f0, m0, status) in cases.items():
        one = reconstruct(p0, f0, m0)
        assert int(one.status[0]) == status, name
        _assert_same(one, reconstruct([p0], [f0], [m0]), 0)
    axial = reconstruct([1, 2, 3], [0, 0, 2.0], [0, 0, 0])
    np.testing.assert_array_equal(axial.point, [[1, 2, 4]])  # tip of the straight rod
    assert axial.s1[0] == 1.0 and axial.phase[0] == 1


def test_single_sample_keeps_the_argument_checks():
    with pytest.raises(ValueError, match="p0 must have shape"):
        reconstruct([0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="same number of samples"):
        reconstruct(np.zeros(3), np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"R_WC must have shape \(3, 3\) or \(2, 3, 3\), got \(3, 3, 3\)"):
        reconstruct(np.zeros((2, 3)), np.ones((2, 3)), np.ones((2, 3)), np.tile(np.eye(3), (3, 1, 1)))


def test_planar_contact_of_an_array_is_each_load_case_alone():
    rng = np.random.default_rng(7)
    fu, fv = rng.normal(size=(2, 3000)) * rng.choice([1e-3, 1.0, 30.0], (2, 3000))
    kappa0 = rng.normal(size=3000) * 2  # both signs: the mirror image too
    fu[:5], fv[:5], kappa0[:5] = [0, np.nan, 0, 0, 0.3], [0, 1, -1, 1e-3, np.inf], [0, 0, 0, 3, 1]
    # ordinary, though k (1 - k) f underflows
    fu[5:7], fv[5:7], kappa0[5:7] = [3e-320, 0.0], [-5e-320, -1e-300], [1e-160, 1e-152]
    kappa0[7] = -0.0  # not mirrored into chi = -pi
    many = planar_contact(fu.reshape(60, 50), fv.reshape(60, 50), kappa0.reshape(60, 50))
    assert many.s1.shape == (60, 50)
    for i in range(len(fu)):
        one = planar_contact_scalar(float(fu[i]), float(fv[i]), float(kappa0[i]))
        row, col = divmod(i, 50)
        got = (many.u1[row, col], many.v1[row, col], many.s1[row, col], many.phi1[row, col])
        np.testing.assert_array_equal(one[:4], got)
        assert one[4] == many.status[row, col]
    assert (many.status.ravel()[5:8] == 0).all() and np.isfinite(many.s1.ravel()[5:8]).all()
    assert many.s1.ravel()[7] == pytest.approx(float(planar_contact(fu[7], fv[7], 0.0).s1), abs=0)


def test_si_step2_with_a_turned_clamp_finds_the_turned_contact() -> None:
    # A Step 1 sweep, the whole scene turned by R and scaled to a rod of L = 0.08 m, EI =
    # 3e-3 N m^2: the wrench in C is unchanged, the contact must be the turned one, in m.
    sweep = simulate_sweep(parse_surface("paraboloid:a=0.5,b=1,h=0.4"), y0=0.2, mu=0.3, step=0.01)
    rod = RodScale(0.08, 3e-3)
    turn = Rotation.from_euler("xyz", [0.4, -1.2, 2.5])
    n = sweep.n_steps
    f0_n, m0_nm = rod.wrench_to_si(sweep.f0, sweep.m0)
    q = np.tile(turn.as_quat(), (n, 1))
    q[1::2] *= -2.5  # the same rotation: -q, and not unit
    got = reconstruct_si(q, turn.apply(sweep.p0) * rod.length_m, f0_n, m0_nm, rod)
    assert got.valid.all()
    np.testing.assert_allclose(got.point_m, turn.apply(sweep.contact) * rod.length_m, rtol=0,
                               atol=1e-12 * rod.length_m)
    np.testing.assert_allclose(got.force_n, turn.apply(sweep.force) * rod.force_n, rtol=0,
                               atol=1e-12 * np.abs(sweep.force).max() * rod.force_n)
    np.testing.assert_allclose(got.s1_m, np.minimum(sweep.s1, 1.0) * rod.length_m, atol=1e-12)
    bad = reconstruct_si(np.zeros((1, 4)), np.zeros((1, 3)), f0_n[:1], m0_nm[:1], rod)
    assert not bad.pose_ok[0] and not bad.valid[0]


def test_step2_flags_finite_inputs_whose_contact_overflows() -> None:
    # EI/L^2 = 0.04 N: f0 = 1e308 N is 2.5e309 in the rod's units, beyond the float range;
    # 1e300 N is not, and has its point (the force dwarfs m0: the contact is at the clamp).
    rod = RodScale(0.05, 1e-4)
    q, p = np.array([[0.0, 0.0, 0.0, 1.0]] * 2), np.zeros((2, 3))
    got = reconstruct_si(q, p, np.array([[1e308, 0, 0], [1e300, 0, 0]]),
                         np.array([[0, 1e-3, 0]] * 2), rod)
    assert got.status[0] == ContactStatus.NON_FINITE_INPUT and not got.valid[0]
    assert np.isnan(got.point_m[0]).all() and np.isnan(got.s1_m[0])
    assert got.valid[1] and np.isfinite(got.point_m[1]).all()
    assert np.linalg.norm(got.point_m[1]) < 1e-12 * rod.length_m
    # Finite and fine in C, the contact force turned 45 deg about x into W is 1.84e308: it was
    # once a usable contact (status OK) with an infinite force.
    turned = reconstruct([[0.0, 0.0, 0.0]], [[0.0, -1.3e308, -1.3e308]], [[1e300, 0.0, 0.0]],
                         Rotation.from_euler("x", 45, degrees=True).as_matrix())
    assert turned.status[0] == ContactStatus.NON_FINITE_INPUT and np.isnan(turned.point[0]).all()
    assert np.isinf(turned.force[0]).any()
    q_turned = Rotation.from_euler("x", 45, degrees=True).as_quat()[None]
    si = reconstruct_si(q_turned, np.zeros((1, 3)), [[0.0, -1.3e308, -1.3e308]],
                        [[1e300, 0.0, 0.0]], RodScale())
    assert si.status[0] == ContactStatus.NON_FINITE_INPUT and not si.valid[0]


@pytest.mark.parametrize("with_covariance", [False, True])
def test_the_tally_counts_each_tick_as_the_flags_say(with_covariance: bool) -> None:
    """`ReconstructionSI.tally` against masks of the flags, tick by tick, on random rows."""
    rng = np.random.default_rng(7)
    n = 200
    flags = [int(f) for f in ContactStatus]
    status = np.zeros(n, np.int32)
    for flag in flags:
        status[rng.random(n) < 0.15] |= flag
    pose_ok = rng.random(n) < 0.9
    covariance = rng.normal(size=(n, 3, 3))
    covariance[rng.random(n) < 0.2, 1, 2] = np.nan
    result = ReconstructionSI(pose_ok, np.zeros((n, 3)), np.zeros(n), np.zeros(n, np.int32),
                              np.zeros((n, 3)), status,
                              covariance if with_covariance else None)
    ends = np.array([0, 17, 17, 90, 199, n])
    valid, counts = result.tally(ends)
    expected_valid = pose_ok & ((status & int(NO_CONTACT)) == 0)
    np.testing.assert_array_equal(valid, expected_valid)
    assert counts.shape == (len(ends), len(TALLY))
    for k, (start, stop) in enumerate(zip([0, *ends[:-1]], ends, strict=True)):
        ok, good, st = pose_ok[start:stop], expected_valid[start:stop], status[start:stop]
        finite = np.isfinite(covariance[start:stop]).all(axis=(1, 2))
        want = {"pose_ok": ok.sum(), "valid": good.sum(),
                "multi_contact": (ok & (st & int(ContactStatus.MULTI_CONTACT) != 0)).sum(),
                "ambiguous": (good & (st & int(ContactStatus.AMBIGUOUS_CONTACT) != 0)).sum(),
                "tip_within_noise": (good & (st & int(ContactStatus.TIP_WITHIN_NOISE) != 0)
                                     ).sum() if with_covariance else 0,
                "no_covariance": (good & ~finite).sum() if with_covariance else 0}
        assert dict(zip(TALLY, counts[k].tolist(), strict=True)) == want
    assert counts[:, TALLY.index("valid")].sum() >= 10  # the flags left valid rows to count
