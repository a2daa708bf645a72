"""Elementary rotations and singularity-safe vector helpers.

Everything here is a pure function of arrays, broadcasting over leading axes. Near singular
points the "double where" keeps gradients finite (as in jaxlie's _so3.py): the unsafe branch
is evaluated on a harmless substitute input, so neither branch produces NaN or inf.
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float


def eps_for(x: ArrayLike) -> float:
    """A tiny positive number for x's dtype: squares below it count as zero."""
    dtype = jnp.asarray(x).dtype
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.float32
    return float(jnp.finfo(dtype).eps) ** 2


def rot_z(angle: Float[ArrayLike, "*b"]) -> Float[Array, "*b 3 3"]:
    """Rotation by `angle` (rad) about Z."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    o, z = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack(
        [jnp.stack([c, -s, z], -1), jnp.stack([s, c, z], -1), jnp.stack([z, z, o], -1)], -2
    )


def rot_y(angle: Float[ArrayLike, "*b"]) -> Float[Array, "*b 3 3"]:
    """Rotation by `angle` (rad) about Y."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    o, z = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack(
        [jnp.stack([c, z, s], -1), jnp.stack([z, o, z], -1), jnp.stack([-s, z, c], -1)], -2
    )


def safe_norm(v: Float[ArrayLike, "*b n"]) -> Float[Array, "*b"]:
    """Euclidean norm whose gradient is finite (zero) at the zero vector."""
    v = jnp.asarray(v)
    sq = jnp.sum(v * v, axis=-1)
    tiny = sq <= eps_for(v)
    return jnp.where(tiny, 0.0, jnp.sqrt(jnp.where(tiny, 1.0, sq)))


def safe_normalize(
    v: Float[ArrayLike, "*b n"], fallback: Float[ArrayLike, "*#b n"]
) -> Float[Array, "*b n"]:
    """v / |v|, or `fallback` where v is (numerically) zero; finite gradients everywhere."""
    v = jnp.asarray(v)
    sq = jnp.sum(v * v, axis=-1, keepdims=True)
    tiny = sq <= eps_for(v)
    safe_v = jnp.where(tiny, jnp.asarray(fallback, v.dtype), v)
    return jnp.where(tiny, fallback, safe_v / jnp.sqrt(jnp.sum(safe_v * safe_v, -1, keepdims=True)))


def safe_atan2(y: Float[ArrayLike, "*b"], x: Float[ArrayLike, "*b"]) -> Float[Array, "*b"]:
    """atan2(y, x), defined as 0 with zero gradient at the origin (instead of NaN)."""
    y, x = jnp.asarray(y), jnp.asarray(x)
    tiny = (x * x + y * y) <= eps_for(x)
    return jnp.where(tiny, 0.0, jnp.arctan2(jnp.where(tiny, 0.0, y), jnp.where(tiny, 1.0, x)))


def skew(v: Float[ArrayLike, "*b 3"]) -> Float[Array, "*b 3 3"]:
    """The cross-product matrix [v]x."""
    v = jnp.asarray(v)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = jnp.zeros_like(x)
    return jnp.stack(
        [jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1), jnp.stack([-y, x, o], -1)], -2
    )


def exp_rotvec(v: Float[ArrayLike, "*b 3"]) -> Float[Array, "*b 3 3"]:
    """exp([v]x): the rotation by |v| (rad) about v / |v|, by Rodrigues' formula; smooth at
    v = 0 (series below a dtype-aware threshold, the unsafe branch fed a harmless value)."""
    v = jnp.asarray(v)
    a2 = jnp.sum(v * v, axis=-1)[..., None, None]
    small = a2 < jnp.sqrt(eps_for(a2))
    safe = jnp.where(small, 1.0, a2)
    a = jnp.sqrt(safe)
    s = jnp.where(small, 1.0 - a2 / 6.0, jnp.sin(a) / a)
    c = jnp.where(small, 0.5 - a2 / 24.0, (1.0 - jnp.cos(a)) / safe)
    K = skew(v)
    return jnp.eye(3, dtype=v.dtype) + s * K + c * matmul3(K, K)


def right_jacobian(v: Float[ArrayLike, "*b 3"]) -> Float[Array, "*b 3 3"]:
    """The right Jacobian of exp at v: vee(exp(v)^T d exp(v)) = J_r(v) dv, the body rate
    of a rotation vector's rate, I - (1 - cos a) / a^2 [v]x + (a - sin a) / a^3 [v]x^2;
    smooth at v = 0 (series, as `exp_rotvec`)."""
    v = jnp.asarray(v)
    a2 = jnp.sum(v * v, axis=-1)[..., None, None]
    small = a2 < jnp.sqrt(eps_for(a2))
    safe = jnp.where(small, 1.0, a2)
    a = jnp.sqrt(safe)
    c = jnp.where(small, 0.5 - a2 / 24.0, (1.0 - jnp.cos(a)) / safe)
    d = jnp.where(small, 1.0 / 6.0 - a2 / 120.0, (a - jnp.sin(a)) / (safe * a))
    K = skew(v)
    return jnp.eye(3, dtype=v.dtype) - c * K + d * matmul3(K, K)


def matmul3(
    a: Float[ArrayLike, "*#b 3 3"], b: Float[ArrayLike, "*#b 3 3"]
) -> Float[Array, "*b 3 3"]:
    """a @ b for stacks of 3x3 matrices, written elementwise: XLA fuses it into one loop,
    which on CPU beats a batched dot of tiny matrices many times over."""
    a, b = jnp.asarray(a), jnp.asarray(b)
    return sum(a[..., :, k : k + 1] * b[..., k : k + 1, :] for k in range(3))


def matvec3(a: Float[ArrayLike, "*#b 3 3"], v: Float[ArrayLike, "*#b 3"]) -> Float[Array, "*b 3"]:
    """a @ v for stacks of 3x3 matrices and 3-vectors, elementwise (see `matmul3`)."""
    a, v = jnp.asarray(a), jnp.asarray(v)
    return sum(a[..., :, k] * v[..., k : k + 1] for k in range(3))


def twist_about_z(
    R: Float[ArrayLike, "*b 3 3"], angle: Float[ArrayLike, "*b"]
) -> Float[Array, "*b 3 3"]:
    """R @ Rz(angle): the frame R turned about its own Z axis."""
    R = jnp.asarray(R)
    c, s = jnp.cos(angle)[..., None], jnp.sin(angle)[..., None]
    x, y = R[..., :, 0], R[..., :, 1]
    return jnp.stack([c * x + s * y, c * y - s * x, R[..., :, 2]], axis=-1)


def rotate_about_z(
    v: Float[ArrayLike, "*b 3"], angle: Float[ArrayLike, "*b"]
) -> Float[Array, "*b 3"]:
    """Rz(angle) @ v."""
    v = jnp.asarray(v)
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], v[..., 2]], -1)


def swing_rotation(
    a: Float[ArrayLike, "*b 3"], b: Float[ArrayLike, "*b 3"]
) -> Float[Array, "*b 3 3"]:
    """The smallest rotation taking unit vector a to unit vector b.

    Where a . b >= 0: R = c I + [v]x + v v^T / (1 + c) with v = a x b, c = a . b (Rodrigues'
    formula with |v|^2 = 1 - c^2), a rational function with no normalisation and exact
    derivatives at b = a. Where a . b < 0 that formula cancels badly, so R is built as the
    turn by the polar angle of b about an axis perpendicular to the meridian from a, measured
    in a fixed frame around a. Exactly at b = -a the smallest rotation is not unique; this
    gives the half-turn about that frame's second axis (a proper rotation, finite gradients).
    """
    a, b = jnp.asarray(a), jnp.asarray(b)
    v = jnp.cross(a, b)
    c = jnp.sum(a * b, axis=-1)
    near = c >= 0.0
    cc = c[..., None, None]
    denom = jnp.where(near, 1.0 + c, 1.0)[..., None, None]
    R_near = cc * jnp.eye(3, dtype=v.dtype) + skew(v) + v[..., :, None] * v[..., None, :] / denom
    # A frame (e1, e2, a) around a, fixed by a alone.
    e1 = jnp.cross(a, jnp.asarray([0.0, 0.0, 1.0], a.dtype))
    e1 = jnp.where(
        jnp.sum(e1 * e1, -1, keepdims=True) < 0.25,
        jnp.cross(a, jnp.asarray([1.0, 0.0, 0.0], a.dtype)),
        e1,
    )
    e1 = e1 / jnp.sqrt(jnp.sum(e1 * e1, -1, keepdims=True))
    e2 = jnp.cross(a, e1)
    F = jnp.stack([e1, e2, a], axis=-1)
    bl = jnp.sum(F * b[..., :, None], axis=-2)  # b in that frame
    theta = safe_atan2(bl[..., 1], bl[..., 0])
    polar = safe_atan2(safe_norm(bl[..., :2]), bl[..., 2])
    local = matmul3(matmul3(rot_z(theta), rot_y(polar)), rot_z(-theta))
    R_far = matmul3(matmul3(F, local), jnp.swapaxes(F, -1, -2))
    return jnp.where(near[..., None, None], R_near, R_far)


def cross_of_axes(direction) -> np.ndarray:
    """Seed 000's cross of axes for a segment pointing along `direction` (world, standard
    position): columns X, Y, Z. Z = direction; X lies in the vertical plane perpendicular to
    world Y with a positive forward component (up if Z points forward or backward, forward
    if Z is along world Y); Y = Z x X. Used at load time on the fixed standard geometry.
    """
    z = np.asarray(direction, dtype=float)
    z = z / np.linalg.norm(z)
    x = np.array([z[2], 0.0, -z[0]])
    n = np.linalg.norm(x)
    if n < 1e-12:
        x = np.array([1.0, 0.0, 0.0])
    else:
        x = x / n
        if x[0] < -1e-12 or (abs(x[0]) <= 1e-12 and x[2] < 0):
            x = -x
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)
