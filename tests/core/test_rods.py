"""Tapered and pre-curved rods: the compiled Kirchhoff rod against the independent reference
(``rod_reference``, scipy's DOP853 shooting in its own formulation), and Step 2's round trip."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.core.rod_reference import solve_rod
from vibrissa.reconstruct import reconstruct
from vibrissa.reconstruct_rods import MAX_CANDIDATES, reconstruct_rod
from vibrissa.rods import RodShape, integrate_to, loaded_rod, rod_line
from vibrissa.status import NO_CONTACT, ContactStatus

AMBIGUOUS = int(ContactStatus.AMBIGUOUS_CONTACT)


def random_rod(rng: np.random.Generator) -> RodShape:
    return RodShape(taper_ratio=rng.uniform(0.3, 1.0), precurvature=rng.uniform(-3.0, 3.0),
                    poisson_ratio=rng.uniform(0.0, 0.5))


def random_load(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    return rng.normal(size=3) * rng.uniform(0.05, 1.5), rng.uniform(0.15, 1.0)


@pytest.mark.parametrize("seed", range(6))
def test_the_forward_problem_matches_the_reference(seed):
    """m0 and the contact point of the same rod and load, by the package's Runge-Kutta rod and
    by the reference's adaptive DOP853 at 1e-12: within the stated discretisation error."""
    rng = np.random.default_rng(seed)
    shape, (force, s1) = random_rod(rng), random_load(rng)
    reference = solve_rod(force, s1, shape.taper_ratio, shape.precurvature, shape.poisson_ratio)
    m0 = loaded_rod(shape, force, s1)
    r1 = integrate_to(s1, -force, m0, shape.params)[:3]
    assert np.abs(m0 - reference.m0).max() < 2e-6
    assert np.abs(r1 - reference.r1).max() < 1e-6
    # beyond the contact the rod is the unloaded arc: the tip too
    tip = rod_line(shape, -force, m0, s1, np.array([s1, 1.0]))
    assert np.abs(tip - reference.shape(np.array([s1, 1.0]))).max() < 1e-6


def test_the_uniform_rod_is_the_closed_form():
    """The general rod with r = 1 and no pre-curvature is the planar elastica: the wrench of a
    contact, handed to the closed form, gives the contact back (to the discretisation)."""
    shape = RodShape()
    rng = np.random.default_rng(3)
    for _ in range(20):
        force, s1 = random_load(rng)
        m0 = loaded_rod(shape, force, s1)
        r1 = integrate_to(s1, -force, m0, shape.params)[:3]
        closed = reconstruct(np.zeros(3), -force, m0)
        assert closed.status[0] == 0
        assert abs(closed.s1[0] - s1) < 1e-6
        assert np.abs(closed.point[0] - r1).max() < 1e-6


def test_step2_of_the_uniform_rod_is_reconstruct_bit_for_bit():
    rng = np.random.default_rng(4)
    p0, f0, m0 = rng.normal(size=(3, 50, 3))
    general, candidates = reconstruct_rod(p0, f0, m0, RodShape())
    closed = reconstruct(p0, f0, m0)
    for name in ("point", "s1", "phase", "psi", "force", "status"):
        np.testing.assert_array_equal(getattr(general, name), getattr(closed, name))
    assert candidates.shape == (50, MAX_CANDIDATES)


def test_step2_recovers_the_reference_contact():
    """The wrench of the independent reference's rod gives its contact point back."""
    rng = np.random.default_rng(11)
    for _ in range(8):
        shape, (force, s1) = random_rod(rng), random_load(rng)
        reference = solve_rod(force, s1, shape.taper_ratio, shape.precurvature,
                              shape.poisson_ratio)
        result, candidates = reconstruct_rod(np.zeros(3), reference.f0, reference.m0, shape)
        listed = candidates[0][np.isfinite(candidates[0])]
        assert np.min(np.abs(listed - s1)) < 2e-6
        if not result.status[0] & AMBIGUOUS:
            assert np.abs(result.point[0] - reference.r1).max() < 2e-6


def test_round_trip_on_a_thousand_random_rods_loads_and_poses():
    """Step 2 of the wrench of a contact on 1 000 random rods (taper 0.3-1, pre-curvature
    +-3 / L, nu 0-0.5), loads and clamp poses: the contact within 1e-6 L where the wrench has
    one candidate, among the candidates otherwise."""
    rng = np.random.default_rng(2026)
    unique = listed = 0
    for _ in range(1000):
        shape, (force, s1) = random_rod(rng), random_load(rng)
        m0 = loaded_rod(shape, force, s1)
        r1 = integrate_to(s1, -force, m0, shape.params)[:3]
        R_WC = Rotation.random(random_state=rng).as_matrix()
        p0 = rng.uniform(-2.0, 2.0, 3)
        result, candidates = reconstruct_rod(p0, -force, m0, shape, R_WC)
        found = candidates[0][np.isfinite(candidates[0])]
        assert np.min(np.abs(found - s1)) < 1e-6, (shape, force, s1, found)
        assert result.status[0] & int(NO_CONTACT) == 0
        if len(found) == 1:
            unique += 1
            assert result.status[0] & AMBIGUOUS == 0
            assert abs(result.s1[0] - s1) < 1e-6
            assert np.abs(result.point[0] - (p0 + R_WC @ r1)).max() < 1e-6
            np.testing.assert_allclose(result.force[0], R_WC @ force, atol=1e-12)
        else:
            listed += 1
            assert result.status[0] & AMBIGUOUS
    assert unique > 900


def test_a_stream_chooses_by_continuity():
    """A pre-curved rod pushed along its curvature at s1 = 0.573: the force's line meets the
    rod a second time nearer the clamp, a contact there gives the same wrench (two candidates).
    Alone, the first is taken and flagged ambiguous; in a stream that comes from s1, s1 is
    taken without a flag."""
    shape = RodShape(taper_ratio=0.5686, precurvature=2.9833)
    force, s1 = np.array([5.601, 0.0, -0.678]), 0.573
    loads = (0.4, 0.6, 0.8, 1.0)
    m0 = np.array([loaded_rod(shape, a * force, s1, load_steps=8) for a in loads])
    f0 = -np.outer(loads, force)
    alone, candidates = reconstruct_rod(np.zeros((4, 3)), f0, m0, shape)
    for row in candidates:
        found = row[np.isfinite(row)]
        assert len(found) == 2 and abs(found[1] - s1) < 1e-6 and found[0] < s1 - 0.1
    assert (alone.status & AMBIGUOUS).all() and (alone.s1 < s1 - 0.1).all()
    stream, _ = reconstruct_rod(np.zeros((4, 3)), f0, m0, shape, previous_s1=s1, stream=True)
    np.testing.assert_allclose(stream.s1, s1, atol=1e-6)
    assert not (stream.status & AMBIGUOUS).any()
    # rows on their own with their previous contact: the same
    each, _ = reconstruct_rod(np.zeros((4, 3)), f0, m0, shape, previous_s1=np.full(4, s1))
    np.testing.assert_array_equal(each.s1, stream.s1)


def test_two_contacts_and_bad_wrenches_are_flagged():
    shape = RodShape(taper_ratio=0.5, precurvature=1.5)
    f_a, f_b = np.array([0.3, 0.2, 0.0]), np.array([-0.1, 0.4, 0.1])
    p_a = integrate_to(0.5, np.zeros(3), np.zeros(3), shape.params)[:3]  # unloaded points
    p_b = integrate_to(0.9, np.zeros(3), np.zeros(3), shape.params)[:3]
    f0 = -(f_a + f_b)
    m0 = -(np.cross(p_a, f_a) + np.cross(p_b, f_b))
    assert abs(f0 @ m0) > 1e-3
    rows = np.array([f0, [np.nan, 0, 0], [0.0, 0.0, 0.0]]), np.array([m0, m0, m0])
    result, _ = reconstruct_rod(np.zeros((3, 3)), *rows, shape)
    assert result.status[0] & int(ContactStatus.MULTI_CONTACT)
    assert result.status[1] & int(ContactStatus.NON_FINITE_INPUT)
    assert result.status[2] & int(ContactStatus.NO_FORCE)
    assert np.isnan(result.point).all()


def test_a_rod_description_out_of_range_is_refused():
    for bad in ({"taper_ratio": 0.0}, {"taper_ratio": 1.5}, {"precurvature": 7.0},
                {"poisson_ratio": -0.1}, {"taper_ratio": float("nan")}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            RodShape(**bad)


def _wrenches(shape, rng, n):
    forces = rng.normal(size=(n, 3)) * rng.uniform(0.1, 1.0, (n, 1))
    s1 = rng.uniform(0.3, 0.95, n)
    m0 = np.array([loaded_rod(shape, f, s) for f, s in zip(forces, s1, strict=True)])
    return -forces, m0, s1


def test_step2_in_si_with_shapes_mixes_rods_row_by_row():
    """reconstruct_si with each row's shape: shaped rows are reconstruct_rod's contacts in SI
    (a rod of 40 mm, EI 2e-5), straight uniform rows the same bits as without shapes."""
    from vibrissa.reconstruct import reconstruct_si
    from vibrissa.units import RodScale

    rng = np.random.default_rng(8)
    shape, rod = RodShape(0.4, 2.0, 0.3), RodScale(0.04, 2e-5)
    f0, m0, s1 = _wrenches(shape, rng, 20)
    uniform_f0, uniform_m0 = rng.normal(size=(2, 20, 3)) * 0.3
    q = Rotation.random(40, random_state=rng).as_quat()
    p = rng.uniform(-1.0, 1.0, (40, 3))
    f0_n, m0_nm = rod.wrench_to_si(np.vstack([f0, uniform_f0]), np.vstack([m0, uniform_m0]))
    shapes = np.vstack([np.tile(shape.params, (20, 1)), np.tile(RodShape().params, (20, 1))])
    mixed = reconstruct_si(q, p, f0_n, m0_nm, rod, shapes=shapes, previous_s1_m=np.r_[
        s1 * rod.length_m, np.full(20, np.nan)])
    plain = reconstruct_si(q[20:], p[20:], f0_n[20:], m0_nm[20:], rod)
    for name in ("point_m", "s1_m", "phase", "force_n", "status"):
        np.testing.assert_array_equal(getattr(mixed, name)[20:], getattr(plain, name))
    alone, _ = reconstruct_rod(p[:20] / rod.length_m, f0, m0, shape,
                               Rotation.from_quat(q[:20]).as_matrix(), previous_s1=s1)
    np.testing.assert_allclose(mixed.point_m[:20], alone.point * rod.length_m, rtol=0,
                               atol=1e-15)
    np.testing.assert_allclose(mixed.s1_m[:20], s1 * rod.length_m, atol=1e-6 * rod.length_m)


def test_a_chain_of_rows_is_the_stream_of_one_whisker():
    from vibrissa.reconstruct import reconstruct_si
    from vibrissa.units import RodScale

    shape, rod = RodShape(0.5686, 2.9833), RodScale(0.05, 1e-5)
    force, s1 = np.array([5.601, 0.0, -0.678]), 0.573  # two candidates (see above)
    loads = (0.4, 0.6, 0.8, 1.0)
    m0 = np.array([loaded_rod(shape, a * force, s1, load_steps=8) for a in loads])
    f0_n, m0_nm = rod.wrench_to_si(-np.outer(loads, force), m0)
    q, p = np.tile([0.0, 0.0, 0.0, 1.0], (4, 1)), np.zeros((4, 3))
    shapes = np.tile(shape.params, (4, 1))
    first = np.r_[s1 * rod.length_m, np.full(3, np.nan)]
    chained = reconstruct_si(q, p, f0_n, m0_nm, rod, shapes=shapes, previous_s1_m=first,
                             chain=np.array([-1, 0, 1, 2]))
    np.testing.assert_allclose(chained.s1_m, s1 * rod.length_m, atol=1e-6 * rod.length_m)
    assert not (chained.status & AMBIGUOUS).any()
    alone = reconstruct_si(q, p, f0_n, m0_nm, rod, shapes=shapes)
    assert (alone.status & AMBIGUOUS).all()
    with pytest.raises(ValueError, match="chain"):
        reconstruct_si(q, p, f0_n, m0_nm, rod, shapes=shapes, chain=np.array([0, 0, 1, 2]))


def test_the_covariance_of_a_shaped_rods_point_is_its_scatter_under_noise():
    """Gaussian wrench noise on a pre-curved tapered rod's wrench: the points' scatter matches
    the first-order covariance (forward differences of the rod's Step 2) within 15 %."""
    from vibrissa.reconstruct import reconstruct_si
    from vibrissa.units import RodScale

    shape, rod = RodShape(0.4, 1.5, 0.3), RodScale(0.04, 2e-5)
    m0 = loaded_rod(shape, np.array([0.4, 0.2, -0.1]), 0.7)
    f0_n, m0_nm = rod.wrench_to_si(-np.array([0.4, 0.2, -0.1]), m0)
    sigma = np.r_[np.full(3, 2e-3 * np.abs(f0_n).max()), np.full(3, 2e-3 * np.abs(m0_nm).max())]
    cov = np.diag(sigma ** 2)
    rng = np.random.default_rng(5)
    noise = rng.normal(size=(4000, 6)) * sigma
    n = len(noise)
    one = np.tile(shape.params, (1, 1))
    predicted = reconstruct_si(np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros((1, 3)), f0_n[None],
                               m0_nm[None], rod, cov, shapes=one).covariance_m2[0]
    noisy = reconstruct_si(np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), np.zeros((n, 3)),
                           f0_n + noise[:, :3], m0_nm + noise[:, 3:], rod, cov,
                           shapes=np.tile(shape.params, (n, 1)),
                           previous_s1_m=np.full(n, 0.7 * rod.length_m))
    assert noisy.valid.all()
    scatter = np.cov(noisy.point_m.T)
    big = np.abs(predicted) > 0.1 * np.abs(predicted).max()
    np.testing.assert_allclose(scatter[big], predicted[big], rtol=0.15)
