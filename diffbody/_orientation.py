"""Segment orientation: spherical coordinates and the standard orientation (seeds 000, 001).

Two spherical conventions, each named for what it holds:

- **azimuth-polar** (seed 000, Badler & O'Rourke): theta is the azimuth about Z from X toward
  Y, phi the polar angle from Z: v = r (sin phi cos theta, sin phi sin theta, cos phi).
- **inclination-azimuth** (seed 001, HumanEva local coordinate systems): theta is the
  inclination from x', phi the azimuth in the y'-z' plane measured from z' toward y':
  v = r (cos theta, sin theta sin phi, sin theta cos phi).

A segment's base frame in its socket is R = Rz(theta) Ry(phi) Rz(s(theta, phi) + tau)
(docs/design.md, section 1), where s is the standard twist of this module.
"""

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._rotations import matmul3, rot_y, rot_z, safe_atan2, safe_norm

LIMBS: tuple[str, ...] = ("left_arm", "right_arm", "left_leg", "right_leg")


def azimuth_polar_to_vector(
    theta: Float[ArrayLike, "*b"], phi: Float[ArrayLike, "*b"], r: Float[ArrayLike, "*b"] = 1.0
) -> Float[Array, "*b 3"]:
    """Seed 000 spherical coordinates (azimuth theta about Z from X, polar phi from Z; rad)
    to a Cartesian vector of length r."""
    theta, phi, r = jnp.broadcast_arrays(theta, phi, r)
    sp = jnp.sin(phi)
    return r[..., None] * jnp.stack([sp * jnp.cos(theta), sp * jnp.sin(theta), jnp.cos(phi)], -1)


def vector_to_azimuth_polar(
    v: Float[ArrayLike, "*b 3"],
) -> tuple[Float[Array, "*b"], Float[Array, "*b"], Float[Array, "*b"]]:
    """Cartesian vector to seed 000 (theta, phi, r). theta in (-pi, pi], phi in [0, pi].

    At the poles theta is undefined; it is returned as 0 with a finite (zero) gradient, and
    at the zero vector phi is 0 as well.
    """
    v = jnp.asarray(v)
    rho = safe_norm(v[..., :2])
    return safe_atan2(v[..., 1], v[..., 0]), safe_atan2(rho, v[..., 2]), safe_norm(v)


def inclination_azimuth_to_vector(
    theta: Float[ArrayLike, "*b"], phi: Float[ArrayLike, "*b"], r: Float[ArrayLike, "*b"] = 1.0
) -> Float[Array, "*b 3"]:
    """Seed 001 spherical coordinates (inclination theta from x', azimuth phi in the
    y'-z' plane from z' toward y'; rad) to a Cartesian vector of length r
    (the seed's SphereToCartCoordinates)."""
    theta, phi, r = jnp.broadcast_arrays(theta, phi, r)
    st = jnp.sin(theta)
    return r[..., None] * jnp.stack([jnp.cos(theta), st * jnp.sin(phi), st * jnp.cos(phi)], -1)


def vector_to_inclination_azimuth(
    v: Float[ArrayLike, "*b 3"],
) -> tuple[Float[Array, "*b"], Float[Array, "*b"], Float[Array, "*b"]]:
    """Cartesian vector to seed 001 (theta, phi, r) (the seed's CartToSphereCoordinates):
    theta = acos(x / r) in [0, pi], phi = atan2(y, z) in (-pi, pi]; finite gradients on the
    x' axis and at zero."""
    v = jnp.asarray(v)
    rho = safe_norm(v[..., 1:])
    return safe_atan2(rho, v[..., 0]), safe_atan2(v[..., 1], v[..., 2]), safe_norm(v)


def azimuth_polar_to_inclination_azimuth(
    theta: Float[ArrayLike, "*b"], phi: Float[ArrayLike, "*b"]
) -> tuple[Float[Array, "*b"], Float[Array, "*b"]]:
    """The same direction from seed 000's (theta, phi) to seed 001's (theta, phi), both
    measured in one frame (x' = X, y' = Y, z' = Z)."""
    t, p, _ = vector_to_inclination_azimuth(azimuth_polar_to_vector(theta, phi))
    return t, p


def inclination_azimuth_to_azimuth_polar(
    theta: Float[ArrayLike, "*b"], phi: Float[ArrayLike, "*b"]
) -> tuple[Float[Array, "*b"], Float[Array, "*b"]]:
    """The inverse of `azimuth_polar_to_inclination_azimuth`."""
    t, p, _ = vector_to_azimuth_polar(inclination_azimuth_to_vector(theta, phi))
    return t, p


def orientation_matrix(
    theta: Float[ArrayLike, "*b"], phi: Float[ArrayLike, "*b"], twist: Float[ArrayLike, "*b"]
) -> Float[Array, "*b 3 3"]:
    """Rz(theta) Ry(phi) Rz(twist) (rad): seed 000's frame erected at the north pole, turned
    by theta, slid down a meridian by phi, then twisted. Its Z column is the direction
    `azimuth_polar_to_vector(theta, phi)`."""
    return matmul3(matmul3(rot_z(theta), rot_y(phi)), rot_z(twist))


def _left_arm_deg(theta: Array, phi: Array) -> Array:
    """Seed 000's five-piece table for the left arm, in degrees, theta in [-90, 270)."""
    back = theta >= 90.0
    upper = phi <= 90.0
    t1 = 180.0 - theta * (1.0 - phi / 90.0)
    t2 = -180.0 * (1.0 - theta / 90.0) + (phi - 270.0) * (theta / 90.0)
    t3 = (theta - 180.0) * (1.0 + (180.0 - phi) / 90.0)
    t4 = 2.0 * (theta - 180.0) * phi / 90.0 - (180.0 + theta) * (1.0 - phi / 90.0)
    # sgn(225 - theta): the seam; on the seam itself we take the theta < 225 side.
    sgn = jnp.where(theta <= 225.0, 1.0, -1.0)
    t5 = (180.0 - theta) * (1.0 - 3.0 * phi / 90.0) + sgn * 360.0 * phi / 90.0
    front_t = jnp.where(upper, t1, t2)
    back_t = jnp.where(upper, jnp.where(theta <= 180.0, t4, t5), t3)
    return jnp.where(back, back_t, front_t)


def _left_leg_deg(theta: Array, phi: Array) -> Array:
    """The left leg's standard twist in degrees, theta in [-180, 180); see standard_twist."""
    lower = theta - 180.0
    upper = 180.0 - theta + 2.0 * theta * phi / 90.0
    return jnp.where(phi >= 90.0, lower, upper)


def standard_twist(
    theta: Float[ArrayLike, "*b"], phi: Float[ArrayLike, "*b"], limb: str
) -> Float[Array, "*b"]:
    """The standard orientation s(theta, phi) (rad) of a limb (seed 000, "Standard
    Orientation"): the twist that, after Rz(theta) Ry(phi), gives the limb's natural frame
    when it points along azimuth theta and polar angle phi of its socket frame.

    - ``"left_arm"``: the seed's five-piece table, linear in theta and phi, continuous
      (modulo a full turn) over the sphere except its seam at theta = 225 deg,
      0 < phi < 90 deg (back, up, across the body), and one frame at each pole. At the
      hanging arm (phi = pi) it gives X forward, Y right, Z down: the cross of axes of the
      standard position.
    - ``"right_arm"``: its mirror image in the sagittal plane. Mirroring Y maps
      Rz(a) to Rz(-a) and keeps Ry, so s_right(theta, phi) = -s_left(-theta, phi); the seam
      moves to theta = 135 deg.
    - ``"left_leg"``: derived the same way (pieces linear in theta and phi, one frame per
      pole, a single seam where the limb cannot go). Lower hemisphere, phi >= 90 deg:
      s = theta - 180 deg, which is exactly the smallest rotation from the hanging leg, so
      flexing, abducting or extending the hip keeps the knee facing the plane of motion (the
      knee points up when the thigh is raised forward, forward when it is abducted, down
      when it is extended backward). Upper hemisphere, phi <= 90 deg:
      s = 180 - theta + 2 theta phi / 90 (deg), theta in [-180, 180): linear in phi from the
      equator (where it equals the lower piece modulo a full turn) to the north pole, where
      theta + s = 180 deg gives the arm's pole frame (X backward, Y right: the thigh raised
      forward past the horizontal continues its flexion). The seam is straight behind,
      theta = 180 deg, 0 < phi < 90 deg: hip extension stops near 15-30 deg below the
      horizontal plane (Merck; 38 CFR 4.71), so no reachable posture lies on it.
    - ``"right_leg"``: the mirror image of the left leg.

    theta may be any angle; phi is clipped to [0, pi].
    """
    if limb not in LIMBS:
        raise ValueError(f"standard_twist: unknown limb {limb!r}; expected one of {LIMBS}")
    theta = jnp.asarray(theta)
    phi_deg = jnp.clip(jnp.rad2deg(jnp.asarray(phi)), 0.0, 180.0)
    sign = -1.0 if limb.startswith("right") else 1.0
    theta_deg = sign * jnp.rad2deg(theta)
    if limb.endswith("arm"):
        t = _left_arm_deg(jnp.mod(theta_deg + 90.0, 360.0) - 90.0, phi_deg)
    else:
        t = _left_leg_deg(jnp.mod(theta_deg + 180.0, 360.0) - 180.0, phi_deg)
    return sign * jnp.deg2rad(t)


def standard_frame(
    theta: Float[ArrayLike, "*b"], phi: Float[ArrayLike, "*b"], limb: str
) -> Float[Array, "*b 3 3"]:
    """The limb's standard-orientation frame Rz(theta) Ry(phi) Rz(s(theta, phi))."""
    return orientation_matrix(theta, phi, standard_twist(theta, phi, limb))
