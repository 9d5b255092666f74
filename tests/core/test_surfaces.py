"""Surfaces: spec parsing, closest points, normals, symmetry."""

import numpy as np
import pytest

from vibrissa.surfaces import Paraboloid, parse_surface

SPECS = [
    "paraboloid:a=0.5,b=1,h=0.4",
    "sphere:r=0.3,cx=0,cy=0,cz=0.8",
    "ellipsoid:rx=0.4,ry=0.3,rz=0.2,cx=0,cy=0,cz=0.9",
    "ellipsoid:rx=0.4,ry=0.3,rz=0.2,cx=0.1,cy=-0.2,cz=0.9,roll=0.3,pitch=-0.2,yaw=1.0",
    "paraboloid:a=0.8,b=0.3,h=0.5,yaw=0.7,pitch=0.1",
]


@pytest.mark.parametrize("spec", SPECS)
def test_closest_point_is_on_the_surface_along_the_normal(spec):
    surface = parse_surface(spec)
    points = np.random.default_rng(3).uniform(-0.6, 0.6, size=(200, 3)) + [0.0, 0.0, 0.8]
    closest = surface.closest_point(points)
    assert np.max(np.abs(surface.value(closest))) < 1e-10
    offset = points - closest
    normal = surface.normal(closest)
    # the offset is collinear with the normal at the closest point
    residual = offset - np.einsum("ni,ni->n", offset, normal)[:, None] * normal
    assert np.max(np.linalg.norm(residual, axis=1)) < 1e-8


@pytest.mark.parametrize("spec", SPECS)
def test_line_intervals_bound_where_points_along_the_line_are_inside(spec):
    """Against the object's own g sampled densely along each line (value < 0 inside)."""
    surface = parse_surface(spec)
    rng = np.random.default_rng(5)
    a = rng.uniform(-0.6, 0.6, size=(300, 3)) + [0.0, 0.0, 0.8]
    d = rng.normal(size=(300, 3))
    d[:5] = [0.0, 0.0, 1.0]  # along a paraboloid's axis: a half-line inside
    t_in, t_out = surface.line_interval(a, d)
    t = np.linspace(-3.0, 3.0, 6001)
    for k in range(len(a)):
        inside = surface.value(a[k] + t[:, None] * d[k]) < 0.0
        if np.isnan(t_in[k]):
            assert not inside.any()
            continue
        within = (t > t_in[k] + 1e-9) & (t < t_out[k] - 1e-9)
        outside = (t < t_in[k] - 1e-9) | (t > t_out[k] + 1e-9)
        assert inside[within].all() and not inside[outside].any()
        for ends in (t_in[k], t_out[k]):
            if np.isfinite(ends):
                assert abs(surface.value(a[k] + ends * d[k])[0]) < 1e-9


@pytest.mark.parametrize("spec", SPECS)
def test_spec_round_trip(spec):
    surface = parse_surface(spec)
    again = parse_surface(surface.spec)
    points = np.random.default_rng(4).normal(size=(50, 3))
    np.testing.assert_allclose(again.value(points), surface.value(points), atol=1e-12)


def test_sphere_signed_distance_is_exact():
    sphere = parse_surface("sphere:r=0.3,cx=0.1,cy=0,cz=0.8")
    points = np.array([[0.1, 0.0, 0.8 + 0.5], [0.1, 0.0, 0.8 + 0.1], [0.1 + 0.3, 0.0, 0.8]])
    np.testing.assert_allclose(sphere.signed_distance(points), [0.2, -0.2, 0.0], atol=1e-15)


def test_paraboloid_normal_is_eq_3_pointing_out_of_the_cup():
    surface = Paraboloid(0.5, 1.0, 0.4)
    x, y = 0.3, -0.2
    n = surface.normal([x, y, 0.5 * x**2 + y**2 + 0.4])[0]
    eq3 = np.array([-2 * 0.5 * x, -2 * 1.0 * y, 1.0]) / np.sqrt(4 * 0.25 * x**2 + 4 * y**2 + 1)
    np.testing.assert_allclose(n, -eq3, atol=1e-15)  # the object is the cup z >= C(x, y)


def test_mirror_symmetry_detection():
    surface = parse_surface("paraboloid:a=0.5,b=1,h=0.4")
    assert surface.is_mirror_symmetric([0, 0, 0], [0, 1, 0])
    assert not surface.is_mirror_symmetric([0, 0.2, 0], [0, 1, 0])


@pytest.mark.parametrize(
    "spec, words",
    [
        ("cube:r=1", "unknown kind"),
        ("sphere:r=1,q=2", "unknown key 'q'"),
        ("sphere:cx=1", "missing r"),
        ("sphere:r=abc", "not a number"),
        ("paraboloid:a=-1,b=1,h=0.4", r"a=-1 is outside \[1e-06, 1000\]"),
        ("sphere:r=1e300", r"r=1e300 is outside \[1e-06, 1000\]"),
        ("sphere:r=1_0", r"r='1_0' is not a number"),  # Python's float reads 10
        ("sphere:r=0.3,r=0.4", r"r given twice"),
        ("sphere:r=\uff11", r"r='\uff11' is not a number"),  # a full-width digit one
        ("ellipsoid:rx=1,ry=1,rz=1,cy=2e6", r"cy=2e6 is outside \[-1000, 1000\]"),
        ("sphere:r", "key=value"),
    ],
)
def test_bad_specs_name_the_problem(spec, words):
    with pytest.raises(ValueError, match=words):
        parse_surface(spec)


@pytest.mark.parametrize("distance", [1e6, 1e7, 4e7])
@pytest.mark.parametrize("radius", [1.0, 5e4])
def test_a_segment_far_from_an_object_is_outside_it(distance, radius):
    """An object 1e6-4e7 rod lengths away (a 0.2 mm whisker and a tower 2 km off): the
    quadratic's t^2 term falls below the test for a paraboloid's axis, and the segment was
    taken for inside all along. Against the distance to the centre, exact here: outside; and
    a segment through the same far ball is inside it where the points are."""
    from vibrissa.frames import Transform
    from vibrissa.surfaces import Sphere

    surface = Sphere(radius, Transform(translation=[distance, 0.0, 0.0]))
    starts = np.array([[0.0, 0.0, 0.0], [0.0, 0.3, 0.0], [0.0, 0.0, -0.7]])
    chords = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.2, 0.7, 0.1]])
    assert not surface.segment_inside(starts, chords).any()
    through = np.array([[distance - 0.5, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]])
    assert surface.segment_inside(*through).all()
    assert np.linalg.norm(through[0] + 0.5 * through[1] - [distance, 0.0, 0.0]) < radius
