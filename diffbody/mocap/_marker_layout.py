"""The unknowns of a marker fit and where its markers ride (`mocap_layout`), and the rigid
start that places a body on measured markers (`rigid_start`; docs/design.md, sections 6 and
7). Positions in m; rotations as (3, 3) matrices or rotation vectors (rad).
"""

import dataclasses

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import Body
from ..anthropometry._scaling import N_GROUPS
from ..files._markerset_file import MarkerSet
from ..problem._unknowns import Layout, make_layout


# --- the unknowns ------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class MocapLayout:
    """What moves and where the markers ride (static): the reach layout of the marked
    segments, each marker's segment and its slot in the layout's chain, and which of
    [posture | log axial scales | log radial scales (n_group each) | offset moves (n, 3)]
    are unknowns."""

    pose: Layout
    segments: tuple[int, ...]
    slots: tuple[int, ...]
    rigid: tuple[bool, ...]  # per marker: rides on the whole body rigidly (`rigid_markers`)
    fit: tuple[str, ...] = ()

    @property
    def sizes(self) -> tuple[int, int, int, int]:
        n_axial = N_GROUPS if "lengths" in self.fit else 0
        n_radial = N_GROUPS if "radii" in self.fit else 0
        n_offsets = 3 * len(self.segments) if "offsets" in self.fit else 0
        return self.pose.n_free, n_axial, n_radial, n_offsets

    def split(self, z: Array) -> tuple[Array, Array, Array, Array]:
        """The posture's free vector, the log axial and radial scales (zero when held) and
        the offset moves (n, 3; zero when held)."""
        x, log_axial, log_radial, moves = jnp.split(z, np.cumsum(self.sizes)[:-1])
        n = len(self.segments)
        zeros = jnp.zeros(N_GROUPS, z.dtype)
        log_axial = log_axial if self.sizes[1] else zeros
        log_radial = log_radial if self.sizes[2] else zeros
        moves = moves.reshape(n, 3) if self.sizes[3] else jnp.zeros((n, 3), z.dtype)
        return x, log_axial, log_radial, moves


def mocap_layout(body: Body, markerset: MarkerSet, fit: tuple[str, ...] = ()) -> MocapLayout:
    """The unknowns of a marker fit: every segment that carries a marker or holds one below
    it, within its limits (segments no marker depends on, the hands of a set without hand
    markers, are neither walked nor moved); the spine as its Bendspine target; the whole
    body's placement. `fit`: the static fit's further unknowns (`_static_fit.FIT_CHOICES`)."""
    marked = sorted(set(markerset.segments))
    paths = {m: body.path_to_top(m) for m in marked}
    movable = {s for path in paths.values() for s in path}
    points = [body.distal_joint[m] for m in marked]
    pose = make_layout(body, points, [], movable, spine=body.spine is not None, root=True)
    slot_of = dict(zip(marked, pose.point_slot))
    slots = tuple(slot_of[s] for s in markerset.segments)
    rigid = rigid_markers(body, [paths[s] for s in markerset.segments])
    return MocapLayout(pose, tuple(markerset.segments), slots, rigid, tuple(fit))


# --- rigid starts ------------------------------------------------------------------------------
def rigid_fit(
    a: Float[Array, "n 3"], b: Float[Array, "n 3"], w: Float[Array, " n"]
) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
    """The rotation R and translation t minimising sum w |R a + t - b|^2 (weighted Kabsch,
    the SVD of the weighted cross-covariance with the reflection removed). No weight: the
    identity."""
    total = jnp.sum(w)
    wn = w / jnp.where(total > 0, total, 1.0)
    ca, cb = wn @ a, wn @ b
    H = (a - ca).T @ (wn[:, None] * (b - cb))
    U, _, Vt = jnp.linalg.svd(H)
    d = jnp.sign(jnp.linalg.det(Vt.T @ U.T))
    R = Vt.T @ jnp.diag(jnp.stack([1.0, 1.0, jnp.where(d == 0, 1.0, d)]).astype(a.dtype)) @ U.T
    ok = (total > 0) & jnp.all(jnp.isfinite(R))
    R = jnp.where(ok, R, jnp.eye(3, dtype=a.dtype))
    return R, jnp.where(ok, cb - R @ ca, 0.0)


def rotation_vector(R: Float[Array, "3 3"]) -> Float[Array, "3"]:
    """The rotation vector (axis times angle in [0, pi]) of a rotation matrix, through its
    unit quaternion (Shepperd: built from the largest of its four squared components, so
    well conditioned at every angle, a half turn included)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    a, b, c = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
    d, e, f = R[0, 1] + R[1, 0], R[0, 2] + R[2, 0], R[1, 2] + R[2, 1]
    # Rows: 4 q_k times the quaternion (w, x, y, z), for k = w, x, y, z.
    q = jnp.stack(
        [
            jnp.stack([1 + tr, a, b, c]),
            jnp.stack([a, 1 + 2 * R[0, 0] - tr, d, e]),
            jnp.stack([b, d, 1 + 2 * R[1, 1] - tr, f]),
            jnp.stack([c, e, f, 1 + 2 * R[2, 2] - tr]),
        ]
    )
    q = q[jnp.argmax(jnp.diagonal(q))]
    q = q * jnp.where(q[0] < 0, -1.0, 1.0) / jnp.linalg.norm(q)
    s = jnp.linalg.norm(q[1:])
    small = s < 1e-6
    angle_over_s = jnp.where(
        small, 2.0 / q[0], 2.0 * jnp.arctan2(s, q[0]) / jnp.where(small, 1.0, s)
    )
    return q[1:] * angle_over_s


def rigid_markers(body: Body, paths: list[tuple[int, ...]]) -> tuple[bool, ...]:
    """Per marker, whether it rides on the whole body rigidly, from its segment's path to the
    top (`Body.path_to_top`): no segment on the path has a range of motion (the pelvis of the
    default body) or is moved by the spine."""
    spine = set(body.spine.segment_names) if body.spine is not None else set()
    ranges = np.concatenate(
        [
            np.asarray(body.swing_hi) - np.asarray(body.swing_lo),
            (np.asarray(body.twist_hi) - np.asarray(body.twist_lo))[:, None],
        ],
        axis=1,
    )

    def rigid(path: tuple[int, ...]) -> bool:
        return all(
            np.all(ranges[p] == 0) and body.segment_names[p] not in spine
            for p in path[:-1]  # without the whole body
        )

    return tuple(rigid(path) for path in paths)


def rigid_start(
    lay: MocapLayout, p_model: Array, target: Array, present: Array, position0: Array
) -> Array:
    """The root part (translation, rotation vector) of a free vector that moves the start
    rigidly onto `target`: fitted on the rigid markers when 3 of them are present, else on
    every present marker."""
    on_rigid = present & np.asarray(lay.rigid, bool)
    w = jnp.where(jnp.sum(on_rigid) >= 3, on_rigid, present).astype(p_model.dtype)
    R, t = rigid_fit(p_model, target, w)
    # Whole-body rotation R about the root joint p0 and a shift: p -> R (p - p0) + p0 + shift.
    return jnp.concatenate([t + R @ position0 - position0, rotation_vector(R)])
