"""The environment a body must not enter (docs/design.md, section 10): planes, spheres,
capsules and boxes, and the signed distance of a sphere to each, exact and differentiable.

A signed distance is positive when the two surfaces are apart, zero when they touch and minus
the depth when they interpenetrate (MuJoCo's `dist`)."""

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._device_arrays import device_array
from .._rotations import safe_norm


def _rows(where: str, values, width: int) -> np.ndarray:
    a = np.asarray([] if values is None else values, float).reshape(-1, width)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"Environment: {where} must be finite numbers, got {a.tolist()}")
    return a


def _flat(item) -> np.ndarray:
    """A shape given as numbers or as a tuple of vectors and numbers, flattened."""
    return np.hstack([np.ravel(np.asarray(x, float)) for x in item])


class Environment(eqx.Module):
    """Shapes fixed in the world (m). Build it with `Environment.of` (or `Environment.floor`).

    planes: (n, 4) a unit normal n and an offset h: the solid side is n . x < h.
    spheres: (n, 4) centre and radius.
    capsules: (n, 7) the two end points of the axis and the radius.
    boxes: (n, 15) centre (3), rotation R_world_box (9, row-major), half sizes (3).
    """

    planes: Float[Array, "n_plane 4"]
    spheres: Float[Array, "n_sphere 4"]
    capsules: Float[Array, "n_capsule 7"]
    boxes: Float[Array, "n_box 15"]

    @classmethod
    def of(
        cls,
        planes: Sequence[tuple] | ArrayLike | None = None,
        spheres: Sequence[tuple] | ArrayLike | None = None,
        capsules: Sequence[tuple] | ArrayLike | None = None,
        boxes: Sequence[tuple] | None = None,
    ) -> "Environment":
        """An environment from plain numbers (host side, checked).

        planes: (normal (3), offset) each, the solid below: ((0, 0, 1), 0.0) is the floor.
        spheres: (centre (3), radius) or 4 numbers each.
        capsules: (end a (3), end b (3), radius) or 7 numbers each.
        boxes: (centre (3), half sizes (3)) or (centre, half sizes, R_world_box (3, 3)).
        """
        plane_rows = []
        for p in [] if planes is None else planes:
            flat = _flat(p)
            if flat.shape != (4,):
                raise ValueError(f"Environment: a plane is a normal (3) and an offset, got {p!r}")
            n, offset = flat[:3], flat[3]
            norm = float(np.linalg.norm(n))
            if not (np.isfinite(norm) and norm > 0):
                raise ValueError(f"Environment: a plane's normal must be non-zero, got {n}")
            plane_rows.append(np.r_[n / norm, float(offset) / norm])
        sphere_rows = [_flat(s) for s in spheres or []]
        capsule_rows = [_flat(c) for c in capsules or []]
        box_rows = []
        for b in boxes or []:
            centre, half = np.asarray(b[0], float), np.asarray(b[1], float)
            R = np.eye(3) if len(b) < 3 else np.asarray(b[2], float)
            if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6):
                raise ValueError(f"Environment: a box's rotation must be a 3x3 rotation, got {R}")
            if half.shape != (3,) or np.any(half < 0):
                raise ValueError(
                    f"Environment: a box's half sizes must be 3 numbers >= 0, got {half}"
                )
            box_rows.append(np.r_[centre, R.ravel(), half])
        spheres_a = _rows("spheres (centre, radius)", sphere_rows, 4)
        capsules_a = _rows("capsules (a, b, radius)", capsule_rows, 7)
        if np.any(spheres_a[:, 3] < 0) or np.any(capsules_a[:, 6] < 0):
            raise ValueError("Environment: radii must be >= 0")
        return cls(
            *(
                device_array(a)
                for a in (
                    _rows("planes", plane_rows, 4),
                    spheres_a,
                    capsules_a,
                    _rows("boxes", box_rows, 15),
                )
            )
        )

    @classmethod
    def floor(cls, height: float = 0.0) -> "Environment":
        """The floor: the plane z = height, solid below."""
        return cls.of(planes=[((0.0, 0.0, 1.0), float(height))])

    @property
    def n_shapes(self) -> int:
        return sum(a.shape[0] for a in (self.planes, self.spheres, self.capsules, self.boxes))

    def shape_names(self) -> tuple[str, ...]:
        """ "plane 0", "sphere 0", "box 0", "box 1", ...: each shape, numbered within its kind
        in the order given, in the order of `sphere_environment_distances`' columns."""
        kinds = ("plane", "sphere", "capsule", "box")
        arrays = (self.planes, self.spheres, self.capsules, self.boxes)
        return tuple(f"{k} {i}" for k, a in zip(kinds, arrays) for i in range(a.shape[0]))


def _box_distance(p: Array, box: Array) -> Array:
    """Signed distance (m) of points p (k, 3) to the surface of boxes (b, 15): (k, b)."""
    centre, R, half = box[:, :3], box[:, 3:12].reshape(-1, 3, 3), box[:, 12:]
    local = jnp.einsum("bji,kbj->kbi", R, p[:, None] - centre[None])  # R^T (p - c)
    q = jnp.abs(local) - half[None]
    outside = safe_norm(jnp.maximum(q, 0.0))
    inside = jnp.minimum(jnp.max(q, axis=-1), 0.0)
    return outside + inside


def sphere_environment_distances(
    centers: Float[Array, "k 3"], radii: Float[Array, " k"], env: Environment
) -> Float[Array, "k n_shape"]:
    """Signed distances (m) from spheres to every shape of the environment (columns in
    `Environment.shape_names` order): planes, spheres, capsules, boxes."""
    r = radii[:, None]
    cols = []
    if env.planes.shape[0]:
        cols.append(centers @ env.planes[:, :3].T - env.planes[:, 3][None] - r)
    if env.spheres.shape[0]:
        d = safe_norm(centers[:, None] - env.spheres[None, :, :3])
        cols.append(d - r - env.spheres[None, :, 3])
    if env.capsules.shape[0]:
        a, b, rc = env.capsules[:, :3], env.capsules[:, 3:6], env.capsules[:, 6]
        ab = b - a
        L2 = jnp.sum(ab * ab, axis=-1)
        t = jnp.sum((centers[:, None] - a[None]) * ab[None], -1) / jnp.where(L2 > 0, L2, 1.0)
        t = jnp.clip(t, 0.0, 1.0)
        nearest = a[None] + t[..., None] * ab[None]
        cols.append(safe_norm(centers[:, None] - nearest) - r - rc[None])
    if env.boxes.shape[0]:
        cols.append(_box_distance(centers, env.boxes) - r)
    if not cols:
        return jnp.zeros((centers.shape[0], 0), centers.dtype)
    return jnp.concatenate(cols, axis=1)
