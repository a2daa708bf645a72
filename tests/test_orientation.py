"""Spherical coordinates and the standard orientation (seeds 000 and 001)."""

import helpers as H
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import diffbody as db
from diffbody._orientation import _PIECES, _pieces, standard_spin, standard_twist_coded

DEG = np.pi / 180
LIMBS = ("left_arm", "right_arm", "left_leg", "right_leg")
angle = st.floats(-np.pi, np.pi, allow_nan=False)
polar = st.floats(0.0, np.pi, allow_nan=False)
MIRROR = np.diag([1.0, -1.0, 1.0])


def frame(theta, phi, limb):
    return np.asarray(db.standard_frame(theta, phi, limb))


# --- spherical coordinates ------------------------------------------------------------


@given(angle, polar, st.floats(0.01, 10))
def test_azimuth_polar_round_trip(theta, phi, r):
    v = db.azimuth_polar_to_vector(theta, phi, r)
    t, p, rr = db.vector_to_azimuth_polar(v)
    np.testing.assert_allclose(db.azimuth_polar_to_vector(t, p, rr), v, atol=1e-12)
    assert abs(rr - r) < 1e-12 and 0 <= p <= np.pi


@given(polar, angle, st.floats(0.01, 10))
def test_inclination_azimuth_round_trip(theta, phi, r):
    v = db.inclination_azimuth_to_vector(theta, phi, r)
    t, p, rr = db.vector_to_inclination_azimuth(v)
    np.testing.assert_allclose(db.inclination_azimuth_to_vector(t, p, rr), v, atol=1e-12)


def test_seed_001_conventions_closed_form():
    # Seed 001's SphereToCartCoordinates: z = r sin t cos p, y = r sin t sin p, x = r cos t.
    t, p, r = 0.7, -1.2, 2.0
    v = np.asarray(db.inclination_azimuth_to_vector(t, p, r))
    np.testing.assert_allclose(
        v, [r * np.cos(t), r * np.sin(t) * np.sin(p), r * np.sin(t) * np.cos(p)]
    )
    # Points on the y' axis have azimuth +-90 degrees.
    assert np.isclose(db.vector_to_inclination_azimuth(jnp.array([0.0, 2.0, 0.0]))[1], np.pi / 2)


@given(angle, polar)
def test_conventions_convert_both_ways(theta, phi):
    t2, p2 = db.azimuth_polar_to_inclination_azimuth(theta, phi)
    t3, p3 = db.inclination_azimuth_to_azimuth_polar(t2, p2)
    np.testing.assert_allclose(
        db.azimuth_polar_to_vector(t3, p3), db.azimuth_polar_to_vector(theta, phi), atol=1e-12
    )
    np.testing.assert_allclose(
        db.inclination_azimuth_to_vector(t2, p2), db.azimuth_polar_to_vector(theta, phi), atol=1e-12
    )


@pytest.mark.parametrize("v", [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
def test_spherical_gradients_finite_at_poles_and_zero(v):
    for f in (db.vector_to_azimuth_polar, db.vector_to_inclination_azimuth):
        jac = jax.jacfwd(lambda x: jnp.stack(f(x)))(jnp.asarray(v))
        jac_r = jax.jacrev(lambda x: jnp.stack(f(x)))(jnp.asarray(v))
        assert np.all(np.isfinite(jac)) and np.all(np.isfinite(jac_r))


def test_orientation_matrix_is_seed_construction():
    theta, phi, tw = 0.3, 1.1, -0.4
    c, s = np.cos, np.sin
    Rz = lambda a: np.array([[c(a), -s(a), 0], [s(a), c(a), 0], [0, 0, 1]])  # noqa: E731
    Ry = lambda a: np.array([[c(a), 0, s(a)], [0, 1, 0], [-s(a), 0, c(a)]])  # noqa: E731
    np.testing.assert_allclose(db.orientation_matrix(theta, phi, tw), Rz(theta) @ Ry(phi) @ Rz(tw))
    np.testing.assert_allclose(
        np.asarray(db.orientation_matrix(theta, phi, tw))[:, 2],
        db.azimuth_polar_to_vector(theta, phi),
    )


# --- the standard orientation -----------------------------------------------------------


def test_left_arm_table_values_from_the_seed():
    # Spot values typed from seed 000's table (degrees).
    cases = [  # theta, phi, t
        (0, 0, 180),
        (45, 45, 180 - 45 * 0.5),
        (0, 135, -180),
        (45, 180, -135),
        (180, 135, 0),
        (135, 45, 2 * (135 - 180) * 45 / 90 - (180 + 135) * 0.5),
        (200, 30, (180 - 200) * (1 - 1) + 360 * 30 / 90),
        (250, 30, (180 - 250) * 0 - 360 * 30 / 90),
    ]
    for th, ph, t in cases:
        got = float(db.standard_twist(th * DEG, ph * DEG, "left_arm")) / DEG
        assert np.isclose(np.mod(got - t + 180, 360) - 180, 0, atol=1e-9), (th, ph, got, t)


@pytest.mark.parametrize("limb", LIMBS)
def test_hanging_limb_has_standard_position_cross_of_axes(limb):
    # X forward, Y right, Z down whatever theta: the consistency check of docs/design.md, section 1.
    for theta in np.linspace(-np.pi, np.pi, 13):
        np.testing.assert_allclose(
            frame(theta, np.pi, limb), np.diag([1.0, -1.0, -1.0]), atol=1e-12
        )


@pytest.mark.parametrize("limb", LIMBS)
def test_one_frame_at_each_pole(limb):
    for pole in (0.0, np.pi):
        frames = [frame(t, pole, limb) for t in np.linspace(-np.pi, np.pi, 25)]
        for f in frames:
            np.testing.assert_allclose(f, frames[0], atol=1e-12)
    # At the north pole the arm raised forward overhead: X backward, Y right.
    np.testing.assert_allclose(frame(0.3, 0.0, limb), np.diag([-1.0, -1.0, 1.0]), atol=1e-12)


SEAMS = {  # (theta of the seam, phi range) in degrees
    "left_arm": (225.0, (0.0, 90.0)),
    "right_arm": (-225.0, (0.0, 90.0)),
    "left_leg": (180.0, (0.0, 90.0)),
    "right_leg": (-180.0, (0.0, 90.0)),
}


def _near_seam(limb, theta, phi, margin):
    seam, (lo, hi) = SEAMS[limb]
    d = np.mod(np.degrees(theta) - seam + 180, 360) - 180
    return abs(d) < margin and lo - margin < np.degrees(phi) < hi + margin


@pytest.mark.parametrize("limb", LIMBS)
@given(theta=angle, phi=polar, dt=st.floats(-1, 1), dp=st.floats(-1, 1))
def test_continuous_off_the_seam(limb, theta, phi, dt, dp):
    """A small step in (theta, phi) moves the frame a little (continuity modulo a full turn,
    since frames compare the twist only through Rz)."""
    h = 1e-6
    phi2 = np.clip(phi + h * dp, 0, np.pi)
    if _near_seam(limb, theta, phi, 1e-3):
        return
    diff = np.abs(frame(theta, phi, limb) - frame(theta + h * dt, phi2, limb)).max()
    assert diff < 1e-4


@pytest.mark.parametrize("limb", LIMBS)
def test_seam_is_a_real_jump(limb):
    seam, _ = SEAMS[limb]
    a = frame((seam - 1e-7) * DEG, 30 * DEG, limb)
    b = frame((seam + 1e-7) * DEG, 30 * DEG, limb)
    assert np.abs(a - b).max() > 0.1


@pytest.mark.parametrize("left, right", [("left_arm", "right_arm"), ("left_leg", "right_leg")])
@given(theta=angle, phi=polar)
def test_right_limb_is_mirror_of_left(left, right, theta, phi):
    # Mirroring Y: M F(theta, phi) M = F_right(-theta, phi).
    np.testing.assert_allclose(
        MIRROR @ frame(theta, phi, left) @ MIRROR, frame(-theta, phi, right), atol=1e-9
    )


def test_leg_lower_hemisphere_is_the_swing_from_hanging():
    # Raising the thigh forward keeps the knee facing up; abducting it keeps it forward.
    np.testing.assert_allclose(frame(0.0, np.pi / 2, "left_leg")[:, 0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(frame(np.pi / 2, np.pi / 2, "left_leg")[:, 0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(frame(np.pi, 2.5, "left_leg")[:, 0][2] < 0, True)


def test_unknown_limb_is_rejected():
    with pytest.raises(ValueError, match="left_arm"):
        db.standard_twist(0.0, 0.0, "left_wing")


@pytest.mark.parametrize("limb", LIMBS)
def test_standard_twist_gradients_finite_at_poles(limb):
    for phi in (0.0, np.pi):
        g = jax.grad(lambda tp: jnp.sum(db.standard_frame(tp[0], tp[1], limb)))(
            jnp.array([0.4, phi])
        )
        assert np.all(np.isfinite(g))


# --- the table over segments of every kind at once (standard_twist_coded) --------------

# Seams, the pieces' borders, the wrap of each table's range, the poles and next to them.
SPECIAL_THETA = np.deg2rad([-270, -225, -180, -135, -90, -45, 0, 45, 90, 135, 180, 225, 270])
SPECIAL_PHI = [0.0, 1e-9, 30 * DEG, np.pi / 2, 150 * DEG, np.pi - 1e-9, np.pi]
directions = st.tuples(
    st.one_of(st.sampled_from(list(SPECIAL_THETA)), st.floats(-7.0, 7.0)),
    st.one_of(st.sampled_from(SPECIAL_PHI), polar),
    st.integers(0, len(LIMBS) - 1),
)


@given(st.lists(directions, min_size=16, max_size=16))
def test_coded_twist_is_each_limbs_own_table(rows):
    """One evaluation over limbs of every kind (a static code per direction, or a traced
    one) gives each limb's own table exactly (unwrapped), and the frame of the seed's
    table typed again (tests/helpers.py) off the seams."""
    theta, phi, code = (np.asarray(c) for c in zip(*rows))
    coded = np.asarray(standard_twist_coded(theta, phi, code))
    traced = np.asarray(_coded_twist(theta, phi, jnp.asarray(code)))
    own = np.choose(code, [np.asarray(db.standard_twist(theta, phi, limb)) for limb in LIMBS])
    np.testing.assert_allclose(coded, own, rtol=0, atol=1e-13)
    np.testing.assert_allclose(traced, own, rtol=0, atol=1e-13)
    frames = np.asarray(db.orientation_matrix(theta, phi, coded))
    for t, p, c, got in zip(theta, phi, code, frames):
        if not _near_seam(LIMBS[c], t, p, 1e-6):
            reference = H.base_in_socket(LIMBS[c], np.zeros(3), t, p)
            np.testing.assert_allclose(got, reference, atol=1e-9)


_coded_twist = jax.jit(standard_twist_coded)


def test_pieces_meet_at_one_frame_per_pole():
    # standard_spin's closed form rests on it: theta + s constant at the north pole
    # (c1 = -1), s - theta at the south one (c1 + 2 k = 1).
    c0, c1, c2, k, pole = _PIECES.T
    assert set(pole) == {1.0, -1.0}
    np.testing.assert_array_equal(c1[pole > 0], -1.0)
    np.testing.assert_array_equal((c1 + 2 * k)[pole < 0], 1.0)


@jax.jit
def _spin_and_autodiff(theta, phi, code):
    """standard_spin's two rates about Z and autodiff's, (S^T dS)_{10} per unit of theta
    and of phi."""

    def frame(t, p):
        return db.orientation_matrix(t, p, standard_twist_coded(t, p, code))

    S = frame(theta, phi)
    _, spin_meridian, spin_parallel = standard_spin(theta, phi, code)
    about_z = []
    for tangent in ((1.0, 0.0), (0.0, 1.0)):
        _, dS = jax.jvp(frame, (theta, phi), tuple(jnp.full_like(theta, x) for x in tangent))
        about_z.append(jnp.sum(S[:, :, 1] * dS[:, :, 0], axis=-1))
    return jnp.stack([spin_parallel * jnp.sin(phi), spin_meridian]), jnp.stack(about_z)


@given(st.lists(directions, min_size=16, max_size=16))
def test_standard_spin_is_the_standard_frames_turn_about_its_axis(rows):
    """S = Rz(theta) Ry(phi) Rz(s) turns about its own Z at spin_meridian dphi +
    spin_parallel sin(phi) dtheta: autodiff of the frame, off the exact poles (where
    autodiff's clip of phi takes half a derivative)."""
    theta, phi, code = (np.asarray(c) for c in zip(*rows))
    phi = np.clip(phi, 1e-9, np.pi - 1e-9)
    s, _, _ = standard_spin(theta, phi, code)
    np.testing.assert_allclose(s, standard_twist_coded(theta, phi, code), rtol=0, atol=1e-15)
    spin, about_z = _spin_and_autodiff(theta, phi, jnp.asarray(code))
    np.testing.assert_allclose(spin, about_z, rtol=0, atol=1e-12)


@pytest.mark.parametrize("code", range(len(LIMBS)))
def test_standard_spin_is_finite_at_the_poles(code):
    """At a pole the spin about the axis is the limit along the piece's meridian,
    (2 k / pi) per unit of sin(phi) dtheta, and its derivatives are finite."""
    theta = jnp.asarray(np.deg2rad([-135.0, -45.0, 45.0, 135.0, 200.0, 250.0]))
    for pole in (0.0, np.pi):
        phi = jnp.full(theta.shape, pole)
        _, _, spin_parallel = standard_spin(theta, phi, code)
        _, _, _, (_, _, _, k, side) = _pieces(theta, phi, code)
        np.testing.assert_allclose(spin_parallel, side * 2 / np.pi * k, atol=1e-15)
        for argnums in (0, 1):
            jac = jax.jacfwd(lambda t, p: jnp.stack(standard_spin(t, p, code)), argnums)
            assert np.all(np.isfinite(jac(theta, phi)))
