"""Measured sphere clouds: checked on the host before a fit (`fit_spheres`), and synthetic
ones for tests, benchmarks and demonstrations."""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._body import Body, Pose
from .._kinematics import forward
from ..problem._problem import make_problem
from ..problem._unknowns import whole_tree_layout


# --- checks --------------------------------------------------------------------------------
def _entry(mask: np.ndarray) -> tuple[int, ...]:
    """The index of the first True entry, as plain ints (for messages)."""
    return tuple(int(i) for i in np.argwhere(mask)[0])


def check_spheres(centers, radii, batch: bool) -> np.ndarray:
    """(..., m, 4) centre and radius per measured sphere, checked on the host."""
    lead = "(b, m" if batch else "(m"
    c = np.asarray(centers, dtype=float)
    r = np.asarray(radii, dtype=float)
    if c.ndim != (3 if batch else 2) or c.shape[-1] != 3:
        raise ValueError(f"centers: expected shape {lead}, 3) in m, got {c.shape}")
    if r.shape != c.shape[:-1]:
        raise ValueError(f"radii: expected shape {lead}) to match centers, got {r.shape}")
    if c.shape[-2] == 0:
        raise ValueError("centers: the cloud holds no sphere; give at least one")
    for name, a in (("centers", c), ("radii", r)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name}: entry {_entry(~np.isfinite(a))} is not finite; give m")
    if np.any(r < 0):
        raise ValueError(f"radii: entry {_entry(r < 0)} is negative; give >= 0 m")
    return np.concatenate([c, r[..., None]], axis=-1)


def check_correspondences(
    correspondences, shape: tuple[int, ...], n_spheres: int
) -> np.ndarray | None:
    """The correspondences (shape) as int32, checked; None when unknown."""
    if correspondences is None:
        return None
    k = np.asarray(correspondences)
    if not np.issubdtype(k.dtype, np.integer):
        raise ValueError(
            "correspondences: expected integers (a model sphere index per measured sphere, "
            f"-1 for none), got {k.dtype}"
        )
    if k.shape == shape[-1:]:
        k = np.broadcast_to(k, shape)
    if k.shape != shape:
        raise ValueError(f"correspondences: expected shape {shape}, got {k.shape}")
    bad = (k < -1) | (k >= n_spheres)
    if np.any(bad):
        raise ValueError(
            f"correspondences: entry {_entry(bad)} = {k[_entry(bad)]} is not a model "
            f"sphere; give 0..{n_spheres - 1}, or -1 for an unmatched (outlier) sphere"
        )
    if np.any(np.all(k < 0, axis=-1)):
        raise ValueError("correspondences: a cloud has no matched sphere; match at least one")
    return k.astype(np.int32)


# --- synthetic clouds ----------------------------------------------------------------------
def sample_pose(body: Body, key: Array, spread: float = 0.5, turn: float = 0.5) -> Pose:
    """A random posture in the fit's pose space: every free joint component at
    mid + half sin(u) of its range with u ~ N(u_rest, spread^2) (the reach core's bounded
    maps: every limit holds), the spine as a Bendspine target drawn the same way, the whole
    body turned about the vertical by up to +-`turn` rad and shifted up to 10 cm. For
    tests, benchmarks and demonstrations of `fit_spheres`."""
    lay = whole_tree_layout(body)
    rest = body.rest_pose()
    problem = make_problem(body, lay, rest)
    k_u, k_turn, k_shift = jax.random.split(key, 3)
    x = problem.x0 + spread * jax.random.normal(k_u, problem.x0.shape, problem.x0.dtype)
    yaw = jax.random.uniform(k_turn, (), problem.x0.dtype, -turn, turn)
    shift = jax.random.uniform(k_shift, (3,), problem.x0.dtype, -0.1, 0.1).at[2].set(0.0)
    x = x.at[-6:].set(jnp.concatenate([shift, jnp.asarray([0.0, 0.0, 1.0]) * yaw]))
    return problem.pose(x, rest)


def synthetic_cloud(
    body: Body, pose: Pose, key: Array, noise: float = 0.0, outliers: float = 0.0
) -> tuple[Array, Array, Array]:
    """A measured cloud of `body` in `pose`: (centers (n_sph, 3) m, radii (n_sph,) m, the
    correspondences (n_sph,)). Every number gets Gaussian noise of `noise` m (radii kept
    >= 0); a fraction `outliers` of the spheres is replaced by spheres drawn uniformly in
    the body's bounding box grown by 10 cm, radii 1-8 cm, with correspondence -1."""
    kin = forward(body, pose)
    centers, radii = kin.sphere_centers, kin.sphere_radii
    n = radii.shape[0]
    k_noise, k_pick, k_where, k_size = jax.random.split(key, 4)
    e = noise * jax.random.normal(k_noise, (n, 4), centers.dtype)
    centers, radii = centers + e[:, :3], jnp.abs(radii + e[:, 3])
    bad = jax.random.permutation(k_pick, n) < round(outliers * n)
    lo, hi = jnp.min(centers, axis=0) - 0.1, jnp.max(centers, axis=0) + 0.1
    where = jax.random.uniform(k_where, (n, 3), centers.dtype, lo, hi)
    size = jax.random.uniform(k_size, (n,), centers.dtype, 0.01, 0.08)
    return (
        jnp.where(bad[:, None], where, centers),
        jnp.where(bad, size, radii),
        jnp.where(bad, -1, jnp.arange(n)),
    )
