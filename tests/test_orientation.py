"""Spherical coordinates and the standard orientation (seeds 000 and 001)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import diffbody as db

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
