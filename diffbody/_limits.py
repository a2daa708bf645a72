"""Joint limits: seed 000's stop function as a differentiable signed violation.

A segment's direction is measured by its swing vector w = (w_x, w_y): the rotation about
the X and Y axes of the segment's standard-position cross of axes that takes its standard
direction to its current direction (w_y > 0 swings +Z toward +X, w_x > 0 toward -Y). Unlike
(theta, phi), w has no singularity at the standard direction, where hanging limbs rest.
Limits (data/SCHEMA.md) are a box on w intersected with a cone |w| <= swing_max, a hinge
(w_x = 0: the segment stays in one plane, as at the elbow and knee), and a twist range.
"""

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._body import PHI, TAU, THETA, Body, Pose
from ._orientation import azimuth_polar_to_vector, vector_to_azimuth_polar
from ._rotations import eps_for

STOP_COLUMNS = (
    "swing_x above",
    "swing_x below",
    "swing_y above",
    "swing_y below",
    "cone",
    "twist above",
    "twist below",
)


def _angle_over_sin(s: Array, c: Array) -> Array:
    """atan2(s, c) / s for s >= 0, with its limit 1 / c near s = 0 (c > 0) and finite
    values and gradients everywhere."""
    small = s * s <= jnp.sqrt(eps_for(s))
    s_safe = jnp.where(small, 1.0, s)
    exact = jnp.arctan2(s_safe, c) / s_safe
    c_safe = jnp.where(c > 0.5, c, 1.0)
    series = 1.0 / c_safe - s * s / (3.0 * c_safe**3)
    # Near the antipode (small s, c < 0) the swing is not unique; keep it finite.
    far = jnp.arctan2(s, c) / jnp.maximum(s, jnp.sqrt(jnp.sqrt(eps_for(s))))
    return jnp.where(small, jnp.where(c > 0.5, series, far), exact)


def _sin_over_angle(a: Array) -> Array:
    """sin(a) / a with its limit 1 at a = 0, finite gradients."""
    small = a * a <= jnp.sqrt(eps_for(a))
    a_safe = jnp.where(small, 1.0, a)
    return jnp.where(small, 1.0 - a * a / 6.0, jnp.sin(a_safe) / a_safe)


def swing_vector(body: Body, angles: Float[Array, "n_seg 3"]) -> Float[Array, "n_seg 2"]:
    """The swing vector (w_x, w_y) (rad) of each segment for pose angles (n_seg, 3)."""
    d_socket = azimuth_polar_to_vector(angles[:, THETA], angles[:, PHI])
    d = jnp.einsum("kji,kj->ki", body.R_socket_rest, d_socket)  # in the rest frame
    rho = jnp.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + eps_for(d)) - jnp.sqrt(eps_for(d))
    k = _angle_over_sin(rho, d[:, 2])
    return jnp.stack([-d[:, 1] * k, d[:, 0] * k], axis=-1)


def angles_from_swing(
    body: Body, swing: Float[Array, "n_seg 2"], twist: Float[Array, " n_seg"]
) -> Float[Array, "n_seg 3"]:
    """Pose angles (theta, phi, tau) from swing vectors and twists (the inverse of
    `swing_vector`, up to theta at the poles)."""
    a = jnp.sqrt(jnp.sum(swing**2, axis=-1) + eps_for(swing)) - jnp.sqrt(eps_for(swing))
    k = _sin_over_angle(a)
    d = jnp.stack([swing[:, 1] * k, -swing[:, 0] * k, jnp.cos(a)], axis=-1)
    d_socket = jnp.einsum("kij,kj->ki", body.R_socket_rest, d)
    theta, phi, _ = vector_to_azimuth_polar(d_socket)
    return jnp.stack([theta, phi, twist], axis=-1)


def stop_violation(body: Body, pose: Pose) -> Float[Array, "n_seg 7"]:
    """Seed 000's stop function as signed violations (rad), <= 0 when admissible.

    Columns (`STOP_COLUMNS`): w_x - hi, lo - w_x, w_y - hi, lo - w_y, the cone
    (|w|^2 - max^2) / (2 max) (smooth, and ~ |w| - max near the boundary), tau - hi,
    lo - tau. A hinge has lo = hi = 0 for w_x, so its first two columns hold it in its
    plane.
    """
    w = swing_vector(body, pose.angles)
    tau = pose.angles[:, TAU]
    cone = (jnp.sum(w * w, axis=-1) - body.swing_max**2) / (2.0 * body.swing_max)
    return jnp.stack(
        [
            w[:, 0] - body.swing_hi[:, 0],
            body.swing_lo[:, 0] - w[:, 0],
            w[:, 1] - body.swing_hi[:, 1],
            body.swing_lo[:, 1] - w[:, 1],
            cone,
            tau - body.twist_hi,
            body.twist_lo - tau,
        ],
        axis=-1,
    )


def within_limits(body: Body, pose: Pose, tol: float | None = None) -> Bool[Array, " n_seg"]:
    """Per segment: True where the pose is admissible (every violation <= tol, in rad).

    The default tol is 256 eps of the computation's dtype (3e-5 rad in float32, 6e-14 rad in
    float64): a pose exactly on a limit rounds to violations of up to ~40 eps, the rest pose
    included, so a bound below float32 rounding would reject it.
    """
    violation = stop_violation(body, pose)
    if tol is None:
        tol = 256 * float(jnp.finfo(violation.dtype).eps)
    return jnp.all(violation <= tol, axis=-1)
