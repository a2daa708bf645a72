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

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from ._rotations import eps_for, matmul3, rot_y, rot_z, safe_atan2, safe_norm

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


# The standard twist's pieces, each bilinear in degrees, s = c0 + c1 theta + c2 phi
# + k theta phi / 90, for the left limbs: seed 000's table for the arm (theta in [-90, 270)),
# the derivation of docs/design.md, section 4, for the leg (theta in [-180, 180)). `pole` is
# the pole a piece reaches (+1 north, phi = 0; -1 south, phi = 180), where theta + s
# (c1 = -1) or s - theta (c1 + 2 k = 1) is constant: one frame per pole (`standard_spin`).
_PIECES = np.array(
    [
        # c0, c1, c2, k, pole
        [180, -1, 0, 1, 1],  # 0 arm, front, upper: 180 - theta (1 - phi / 90)
        [-180, -1, 0, 1, -1],  # 1 arm, front, lower: -180 (1 - theta / 90) + (phi - 270) theta / 90
        [-540, 3, 2, -1, -1],  # 2 arm, back, lower: (theta - 180) (1 + (180 - phi) / 90)
        [-180, -1, -2, 3, 1],  # 3 arm, back, upper, theta <= 180:
        #                         2 (theta - 180) phi / 90 - (180 + theta) (1 - phi / 90)
        [180, -1, -2, 3, 1],  # 4 arm, back, upper, theta in (180, 225]:
        #                        (180 - theta) (1 - 3 phi / 90) + sgn(225 - theta) 360 phi / 90
        [180, -1, -10, 3, 1],  # 5 arm, back, upper, theta > 225 (past the seam): the same
        [180, -1, 0, 2, 1],  # 6 leg, upper (phi < 90): 180 - theta + 2 theta phi / 90
        [-180, 1, 0, 0, -1],  # 7 leg, lower (phi >= 90): theta - 180
    ],
    dtype=float,
)
_ARM = np.asarray([limb.endswith("arm") for limb in LIMBS])
_SIGN = np.asarray([-1.0 if limb.startswith("right") else 1.0 for limb in LIMBS])


def _select(cond, a, b) -> Array:
    """jnp.where(cond, a(), b()), building only the branch that a static (NumPy) condition
    takes when it takes one."""
    if isinstance(cond, np.ndarray | np.bool_) and (np.all(cond) or not np.any(cond)):
        return a() if np.all(cond) else b()
    return jnp.where(cond, a(), b())


def _pieces(theta, phi, code) -> tuple[Array, Array, ArrayLike, tuple[Array, ...]]:
    """For directions (theta, phi) (rad) of limbs coded `code` (indices into LIMBS, static
    NumPy or traced): the left limb's (theta, phi) in degrees (theta mirrored for a right
    limb and wrapped into its table's range, phi clipped to [0, 180]), the mirror sign, and
    the coefficients (c0, c1, c2, k, pole) of each direction's piece of `_PIECES`."""
    theta_deg, phi_deg = jnp.rad2deg(jnp.asarray(theta)), jnp.rad2deg(jnp.asarray(phi))
    dtype = jnp.result_type(theta_deg, phi_deg)
    xp = jnp if isinstance(code, jax.Array) else np
    arm, sign = xp.asarray(_ARM)[code], xp.asarray(_SIGN, dtype)[code]
    offset = xp.where(arm, 90.0, 180.0).astype(dtype)
    theta_deg = jnp.mod(sign * theta_deg + offset, 360.0) - offset
    phi_deg = jnp.clip(phi_deg, 0.0, 180.0)

    def arm_row():
        # The seam, sgn(225 - theta): on the seam itself, the theta < 225 side.
        upper = jnp.where(theta_deg <= 180.0, 3, jnp.where(theta_deg <= 225.0, 4, 5))
        back = jnp.where(phi_deg <= 90.0, upper, 2)
        return jnp.where(theta_deg >= 90.0, back, jnp.where(phi_deg <= 90.0, 0, 1))

    row = _select(arm, arm_row, lambda: jnp.where(phi_deg >= 90.0, 7, 6))
    coefficients = jnp.moveaxis(jnp.asarray(_PIECES, dtype)[row], -1, 0)
    return theta_deg, phi_deg, sign, tuple(coefficients)


def _twist(theta_deg, phi_deg, sign, coefficients) -> Array:
    """The standard twist (rad) from `_pieces`."""
    c0, c1, c2, k, _ = coefficients
    return sign * jnp.deg2rad(c0 + theta_deg * (c1 + k * phi_deg / 90.0) + c2 * phi_deg)


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
    return standard_twist_coded(theta, phi, LIMBS.index(limb))


def standard_twist_coded(
    theta: Float[ArrayLike, "*b"], phi: Float[ArrayLike, "*b"], code: Int[ArrayLike, "*#b"]
) -> Float[Array, "*b"]:
    """`standard_twist` of limbs given as codes, indices into LIMBS (a NumPy array or int,
    or traced), one per direction: one evaluation for segments of every kind."""
    return _twist(*_pieces(theta, phi, code))


def standard_spin(
    theta: Float[ArrayLike, "*b"], phi: Float[ArrayLike, "*b"], code: Int[ArrayLike, "*#b"]
) -> tuple[Float[Array, "*b"], Float[Array, "*b"], Float[Array, "*b"]]:
    """The standard twist s of limbs coded `code` (`standard_twist_coded`) and how fast the
    standard frame S = Rz(theta) Ry(phi) Rz(s) turns about its own Z as its Z axis moves.

    Returns (s, spin_meridian, spin_parallel): S's body rate about its Z is
    spin_meridian dphi + spin_parallel sin(phi) dtheta, for the direction moving by dphi
    along its meridian and by sin(phi) dtheta along its parallel. From the Euler angles
    that rate is cos(phi) dtheta + ds, so spin_meridian = ds/dphi and
    spin_parallel = (cos(phi) + ds/dtheta) / sin(phi). On each bilinear piece
    ds/dtheta = c1 + B phi with B = 2 k / pi, and one frame per pole makes c1 = -1 on the
    pieces that reach the north pole and c1 + B pi = 1 on those that reach the south one;
    the quotient is then B x / sin(x) - tan(x / 2) (north, x = phi) or its negative (south,
    x = pi - phi): finite, and accurate up to the poles (docs/design.md, section 4). At a
    pole itself it is the limit along the piece's meridians.
    """
    theta_deg, phi_deg, sign, coefficients = _pieces(theta, phi, code)
    _, _, c2, k, pole = coefficients
    x = jnp.deg2rad(jnp.where(pole > 0, phi_deg, 180.0 - phi_deg))  # in [0, pi / 2]
    small = x * x < jnp.sqrt(eps_for(x))
    safe = jnp.where(small, 1.0, x)
    x_over_sin = jnp.where(small, 1.0 + x * x / 6.0, safe / jnp.sin(safe))
    spin_parallel = pole * (2.0 / jnp.pi * k * x_over_sin - jnp.tan(x / 2.0))
    spin_meridian = sign * (c2 + k * theta_deg / 90.0)
    return _twist(theta_deg, phi_deg, sign, coefficients), spin_meridian, spin_parallel


def standard_frame(
    theta: Float[ArrayLike, "*b"], phi: Float[ArrayLike, "*b"], limb: str
) -> Float[Array, "*b 3 3"]:
    """The limb's standard-orientation frame Rz(theta) Ry(phi) Rz(s(theta, phi))."""
    return orientation_matrix(theta, phi, standard_twist(theta, phi, limb))
