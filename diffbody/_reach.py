"""Reach: inverse kinematics with optimistix (DESIGN section 6).

Targets put named points of the body (joints, sphere features, the center of gravity) on
positions and segment axes along directions. The unknowns are every movable segment's swing
vector and twist, the spine as its Bendspine target 3-vector (so the 54 vertebra angles move
as a spine), and optionally the whole body's placement. Joint limits hold exactly: each
unknown is a bounded map of a free variable (mid + half sin(u) into [lo, hi], the swing then
pulled radially into its cone), so the solver cannot leave the admissible set.
"""

import inspect
from collections.abc import Sequence
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, ArrayLike, Bool, Float, Int

# The implicit function theorem as optimistix's own solves apply it (ImplicitAdjoint), here
# around the whole multi-start loop; pyproject pins optimistix's minor version for it.
from optimistix.internal import implicit_jvp

from ._body import Body, Pose
from ._kinematics import (
    Kinematics,
    exp_swing,
    feature_points,
    forward,
    forward_frames,
    pose_frames,
    socket_frames_from_swing,
    spine_deviation,
)
from ._limits import angles_from_swing, swing_vector, within_limits
from ._posture import _angles_of_rotation, _pose_from_joints
from ._rotations import matmul3, rot_z, skew, twist_about_z

# Regularisation toward the initial posture, per unit of the free variables: it resolves
# redundancy (a whole arm plus a spine reach one point) without moving reachable targets by
# more than micrometres. The trunk weighs more than the limbs (SPINE_PREFERENCE), so the
# arm reaches what it can and the spine bends for the rest, as people do.
REGULARISATION = 1e-6
SPINE_PREFERENCE = 30.0


@dataclass(frozen=True)
class Target:
    """One reach target; build it with the class methods. Host-side description: names are
    resolved into indices by `solve_reach`."""

    kind: str  # "point", "axis"
    name: str  # "left_hand.palm", "left_wrist", "center_of_gravity", or a segment for axes
    value: np.ndarray | Array  # (3,) position (m) or direction (unit); traced under jax.grad
    axis: np.ndarray | None = None  # (3,) axis in the segment's frame, for "axis"
    weight: float = 1.0

    @classmethod
    def position(
        cls, name: str, xyz: ArrayLike | Sequence[float | int], weight: float = 1.0
    ) -> "Target":
        """Put a joint ("left_wrist"), a feature ("left_hand.palm") or "center_of_gravity"
        at `xyz` (m, world)."""
        value = xyz if isinstance(xyz, jax.Array) else np.asarray(xyz, float)
        return cls("point", name, value, None, float(weight))

    @classmethod
    def axis_direction(
        cls,
        segment: str,
        axis: ArrayLike | Sequence[float | int],
        direction: ArrayLike | Sequence[float | int],
        weight: float = 1.0,
    ) -> "Target":
        """Turn `axis` (in the segment's twisted frame, e.g. the palm normal (0, 1, 0) of the
        left hand) to point along `direction` (world)."""
        a, d = np.asarray(axis, float), np.asarray(direction, float)
        return cls("axis", segment, d / np.linalg.norm(d), a / np.linalg.norm(a), float(weight))

    @classmethod
    def frame(cls, segment: str, R_world_segment: ArrayLike, weight: float = 1.0) -> list["Target"]:
        """A full orientation: the segment's X and Z axes along the columns of R."""
        R = np.asarray(R_world_segment, float)
        return [
            cls.axis_direction(segment, e, R[:, k], weight)
            for k, e in ((0, [1, 0, 0]), (2, [0, 0, 1]))
        ]


class TargetSet(eqx.Module):
    """Targets as arrays (one problem; batch them with a leading axis)."""

    point_index: Int[Array, " n_p"]  # into [joints, features, center of gravity]
    point_xyz: Float[Array, "n_p 3"]
    point_weight: Float[Array, " n_p"]
    axis_segment: Int[Array, " n_a"]
    axis_local: Float[Array, "n_a 3"]
    axis_direction: Float[Array, "n_a 3"]
    axis_weight: Float[Array, " n_a"]


class ReachResult(eqx.Module):
    """What `solve_reach` returns; per-target arrays follow the order the targets were given
    in (a `Target.frame` counts as two targets, its X then its Z axis)."""

    pose: Pose
    reached: Bool[Array, " n_targets"]  # within the tolerance (1 mm / 1 degree by default)
    residuals: Float[Array, " n_targets"]  # m for points, rad for axes
    valid: Bool[Array, " n_targets"]  # False for a non-finite target (then never reached)
    status: Int[Array, ""]  # optimistix.RESULTS index; 0 = successful
    steps: Int[Array, ""]


def resolve_targets(body: Body, targets: Sequence[Target]) -> tuple[TargetSet, list[int]]:
    """Names to indices (host side). Returns the arrays and the original order of targets."""
    points = [t for t in targets if t.kind == "point"]
    axes = [t for t in targets if t.kind == "axis"]
    n_j, n_f = body.n_joints, len(body.feature_names)

    def point_index(name: str) -> int:
        if name == "center_of_gravity":
            return n_j + n_f
        if "." in name:
            return n_j + body.feature_index(name)
        if name in body.joint_names:
            return body.joint_index(name)
        raise KeyError(
            f"unknown effector {name!r}: use a joint ({', '.join(body.joint_names[1:])}), "
            f"a feature ({', '.join(body.feature_names)}) or 'center_of_gravity'"
        )

    for t in targets:
        if np.shape(t.value) != (3,):
            raise ValueError(
                f"target {t.name!r}: expected 3 numbers, got shape {np.shape(t.value)}"
            )
    order = [i for i, t in enumerate(targets) if t.kind == "point"]
    order += [i for i, t in enumerate(targets) if t.kind == "axis"]
    ts = TargetSet(
        point_index=jnp.asarray([point_index(t.name) for t in points], int).reshape(-1),
        point_xyz=jnp.stack([jnp.asarray(t.value) for t in points]).reshape(-1, 3)
        if points
        else jnp.zeros((0, 3)),
        point_weight=jnp.asarray([t.weight for t in points]).reshape(-1),
        axis_segment=jnp.asarray([body.segment_index(t.name) for t in axes], int).reshape(-1),
        axis_local=jnp.asarray(np.asarray([t.axis for t in axes]).reshape(-1, 3)),
        axis_direction=jnp.asarray(np.asarray([t.value for t in axes]).reshape(-1, 3)),
        axis_weight=jnp.asarray([t.weight for t in axes]).reshape(-1),
    )
    return ts, order


@dataclass(frozen=True)
class _Layout:
    """Which pose quantities are unknowns, and which segments the solver walks (static).

    The solver computes only the effectors' chains: a target on the left palm walks the
    whole body, pelvis, spine, clavicle, arm and hand, and only the segments at or below the
    first unknown are recomputed at each step (the rest are read off the start pose once).
    A center-of-gravity target, or a re-rooted body, walks the whole tree.
    """

    swing_x: tuple[int, ...]  # segments whose w_x is free
    swing_y: tuple[int, ...]
    twist: tuple[int, ...]
    spine: bool
    root: bool
    points: tuple[int, ...]  # point targets: into [joints, features, center of gravity]
    axes: tuple[int, ...]  # segments of axis targets
    live: tuple[int, ...]  # chain segments recomputed at each step, parents first
    full: bool  # walk the whole tree (center of gravity, re-rooted body)
    keep_twist: tuple[int, ...]  # twists targets depend on (kept by the post-projection)
    project: bool  # the solver moves twists that no target depends on


def _point_segment(body: Body, index: int) -> int:
    """The segment a point target rides on: a joint's segment ends there; a feature's sphere."""
    n_j = body.n_joints
    if index < n_j:
        return max(index - 1, 0)  # joint j >= 1 is segment j-1's distal joint; 0 the root
    return body.sphere_segment[body.feature_sphere[index - n_j]]


def _layout(
    body: Body,
    points: Sequence[int],
    axes: Sequence[int],
    use_spine: bool,
    free_root: bool,
    segments: Sequence[str] | None,
) -> _Layout:
    spine_segs = set(body.spine.segment_names) if (use_spine and body.spine) else set()
    cog = body.n_joints + len(body.feature_names)
    full = cog in points or body.root_joint != body.default_root_joint
    parent = np.asarray(body.parent)
    chain: set[int] = set(range(body.n_segments)) if full else set()
    for seg in [_point_segment(body, i) for i in points] + list(axes):
        while seg >= 0:
            chain.add(seg)
            seg = int(parent[seg])
    allowed = chain
    if segments is not None:
        allowed = {body.segment_index(name) for name in segments} & chain
    lo, hi = np.asarray(body.swing_lo), np.asarray(body.swing_hi)
    tlo, thi = np.asarray(body.twist_lo), np.asarray(body.twist_hi)
    names = body.segment_names
    movable = sorted(i for i in allowed if i > 0 and names[i] not in spine_segs)
    spine = bool(spine_segs) and any(names[i] in spine_segs for i in allowed)
    swing_x = tuple(i for i in movable if hi[i, 0] > lo[i, 0])
    swing_y = tuple(i for i in movable if hi[i, 1] > lo[i, 1])
    twist = tuple(i for i in movable if thi[i] > tlo[i])
    moved = set(swing_x + swing_y + twist) | ({0} if free_root else set())
    moved |= {i for i in chain if spine and names[i] in spine_segs}
    # A twist moves the targets on its segment and below, off the joints (features, axes);
    # joint positions never depend on it (pose_from_joint_positions).
    keep: set[int] = {0} | {i for i in chain if names[i] in spine_segs}
    off_axis = [_point_segment(body, i) for i in points if i >= body.n_joints] + list(axes)
    for seg in list(range(body.n_segments)) if cog in points else off_axis:
        while seg >= 0 and seg not in keep:
            keep.add(seg)
            seg = int(parent[seg])
    # A hinge swings in its parent's twisted frame: resetting the parent's twist would turn
    # the hinge plane away from a bent joint, so the parent keeps its twist.
    keep |= {int(parent[i]) for i in range(body.n_segments) if body.limit_kind[i] == "hinge"}
    depth = {i: d for d, level in enumerate(body.levels) for i in level}
    live = []
    for i in sorted(chain, key=lambda i: (depth[i], i)):
        if i in moved or (parent[i] >= 0 and int(parent[i]) in live):
            live.append(i)
    return _Layout(
        swing_x=swing_x,
        swing_y=swing_y,
        twist=twist,
        spine=spine,
        root=free_root,
        points=tuple(int(i) for i in points),
        axes=tuple(int(i) for i in axes),
        live=tuple(live),
        full=full,
        keep_twist=tuple(sorted(keep)),
        project=bool(set(twist) - keep),
    )


# The bounded map of each free variable: v = mid + half sin(u). Unlike a logistic squash it
# reaches its bounds at finite u (a target at a joint limit converges instead of crawling
# toward an asymptote) and its slope never vanishes inside the range.
def _squash(u, lo, hi):
    return 0.5 * (lo + hi) + 0.5 * (hi - lo) * jnp.sin(u)


def _unsquash(v, lo, hi):
    # Start inside the range: at the bounds the map's slope is zero, and a limb straight at
    # its stop (the elbow in the standard position) is a singular start for a reach.
    f = jnp.clip((2 * v - lo - hi) / jnp.where(hi > lo, hi - lo, 1.0), -0.9, 0.9)
    return jnp.arcsin(f)


class _Unknowns(eqx.Module):
    swing_x: Array  # free variables of the swing components that can move
    swing_y: Array
    twist: Array
    spine: Array  # (3,) or (0,): the Bendspine target
    root: Array  # (6,) or (0,): translation (m) and rotation vector (rad) of the placement


def _rotvec_to_matrix(v: Array) -> Array:
    """exp([v]x) by Rodrigues' formula, smooth at zero."""
    a2 = jnp.sum(v * v)
    small = a2 < 1e-8
    safe = jnp.where(small, 1.0, a2)
    s = jnp.where(small, 1.0 - a2 / 6.0, jnp.sin(jnp.sqrt(safe)) / jnp.sqrt(safe))
    c = jnp.where(small, 0.5 - a2 / 24.0, (1.0 - jnp.cos(jnp.sqrt(safe))) / safe)
    K = skew(v)
    return jnp.eye(3, dtype=v.dtype) + s * K + c * (K @ K)


class _Start(eqx.Module):
    """The start pose's frames, computed once per solve (outside the solver's loop)."""

    R_socket_base: Array  # (n_seg, 3, 3)
    tau: Array  # (n_seg,)
    fk: Kinematics


class _Problem(eqx.Module):
    """Everything fixed during one solve: the body, which unknowns exist, the start."""

    body: Body
    layout: _Layout = eqx.field(static=True)
    init: Pose
    init_swing: Array  # (n_seg, 2)

    def state(self, x: _Unknowns, start: _Start, idx: Sequence[int] | np.ndarray):
        """Swing vectors (k, 2) and twists (k,) of segments `idx` (which hold every moving
        one), the whole body's base frame, position and spine target of the unknowns: box
        map, then the radial pull into the cone, so every limit holds exactly. Only the
        rows in `idx` are computed: the solver's chain walk needs a handful of segments."""
        b, lay = self.body, self.layout
        row = {seg: k for k, seg in enumerate(idx)}
        idx = np.asarray(idx, int)

        def rows(segs):
            return np.asarray([row[i] for i in segs], int), np.asarray(segs, int)

        (kx, xs), (ky, ys), (kt, ts) = rows(lay.swing_x), rows(lay.swing_y), rows(lay.twist)
        w = self.init_swing[idx]
        w = w.at[kx, 0].set(_squash(x.swing_x, b.swing_lo[xs, 0], b.swing_hi[xs, 0]))
        w = w.at[ky, 1].set(_squash(x.swing_y, b.swing_lo[ys, 1], b.swing_hi[ys, 1]))
        norm2 = jnp.sum(w * w, axis=-1)
        over = norm2 > b.swing_max[idx] ** 2
        safe = jnp.where(over, norm2, 1.0)
        w = w * jnp.where(over, b.swing_max[idx] / jnp.sqrt(safe), 1.0)[:, None]
        tau = self.init.angles[idx, 2].at[kt].set(_squash(x.twist, b.twist_lo[ts], b.twist_hi[ts]))
        base0 = start.R_socket_base[0]  # the start's, built once per solve
        position = self.init.position
        if lay.root:
            base0 = _rotvec_to_matrix(x.root[3:]) @ base0
            position = position + x.root[:3]
        spine_target = None
        if lay.spine:
            spine_target = _squash(x.spine, b.spine.lower.sum(0), b.spine.upper.sum(0))
        return w, tau, base0, position, spine_target

    def frames(self, x: _Unknowns, start: _Start, idx: Sequence[int] | np.ndarray):
        """Base frames in their sockets and twists of segments `idx` for the unknowns: from
        swing vectors (smooth at the poles) where they move, from the start otherwise."""
        b, lay = self.body, self.layout
        w, tau, base0, position, spine_target = self.state(x, start, idx)
        moving = set(lay.swing_x + lay.swing_y + lay.twist)
        k_mov = np.asarray([k for k, i in enumerate(idx) if i in moving], int)
        k_tw = np.asarray([k for k, i in enumerate(idx) if i in lay.twist], int)
        seg = np.asarray(idx, int)
        R = start.R_socket_base[seg]
        if len(k_mov):
            R = R.at[k_mov].set(socket_frames_from_swing(b, w[k_mov], seg[k_mov]))
        if 0 in idx:
            R = R.at[list(idx).index(0)].set(base0)
        tau = start.tau[seg].at[k_tw].set(tau[k_tw])
        if spine_target is not None:
            spine_segs, w_sp, t_sp = spine_deviation(b, spine_target)
            row = {s: k for k, s in enumerate(idx)}
            mine = [(j, row[s]) for j, s in enumerate(np.asarray(spine_segs)) if s in row]
            j, k = (np.asarray(v, int) for v in zip(*mine)) if mine else (np.zeros(0, int),) * 2
            R = R.at[k].set(matmul3(b.R_socket_rest[spine_segs[j]], exp_swing(w_sp[j])))
            tau = tau.at[k].set(t_sp[j])
        return R, tau, position

    def effectors(self, x: _Unknowns, start: _Start):
        """World positions of the point targets (k, 3) and axes of the axis targets (m, 3)."""
        b, lay = self.body, self.layout
        if lay.full:
            all_seg = np.arange(b.n_segments)
            R, tau, position = self.frames(x, start, all_seg)
            fk = forward_frames(b, R, tau, position)
            points = jnp.concatenate(
                [fk.joint_positions, fk.feature_points, fk.center_of_gravity[None]]
            )
            axes = fk.R_world_twisted[np.asarray(lay.axes, int)]
            return points[np.asarray(lay.points, int)], axes
        live = np.asarray(lay.live, int)
        R_sb, tau_live, position = self.frames(x, start, live)
        fk0 = start.fk
        # The chain walk: each live segment hangs from its parent's twisted frame at the
        # parent's distal joint (recomputed if the parent is live, else the start's).
        R_base, R_tw, p_prox, p_dist, tau = {}, {}, {}, {}, {}
        for k, i in enumerate(lay.live):
            R_local = b.R_parent_socket[i] @ R_sb[k]
            par = b.parent[i]
            if par < 0:
                R_base[i], p_prox[i] = R_local, position
            elif par in R_tw:
                R_base[i], p_prox[i] = R_tw[par] @ R_local, p_dist[par]
            else:
                R_base[i] = fk0.R_world_twisted[par] @ R_local
                p_prox[i] = fk0.joint_positions[b.distal_joint[par]]
            tau[i] = tau_live[k]
            R_tw[i] = twist_about_z(R_base[i], tau[i])
            p_dist[i] = p_prox[i] + R_base[i][:, 2] * b.lengths[i]

        def point(index: int) -> Array:
            if index < b.n_joints:
                seg = max(index - 1, 0)
                if seg not in R_base:
                    return fk0.joint_positions[index]
                return p_prox[seg] if index == 0 else p_dist[seg]
            f = index - b.n_joints
            seg = _point_segment(b, index)
            if seg not in R_base:
                return fk0.feature_points[f]
            xyz, _ = feature_points(
                b, np.asarray([f]), R_base[seg][None], p_prox[seg][None], tau[seg][None]
            )
            return xyz[0]

        def axis(seg: int) -> Array:
            return R_tw[seg] if seg in R_tw else fk0.R_world_twisted[seg]

        points = [point(i) for i in lay.points]
        axes = [axis(i) for i in lay.axes]
        return (
            jnp.stack(points) if points else jnp.zeros((0, 3)),
            jnp.stack(axes) if axes else jnp.zeros((0, 3, 3)),
        )

    def pose(self, x: _Unknowns, start: _Start) -> Pose:
        """The public pose of the unknowns (theta, phi, tau rows; the spine as its target)."""
        n = self.body.n_segments
        w, tau, base0, position, spine_target = self.state(x, start, range(n))
        angles = angles_from_swing(self.body, w, tau)
        angles = angles.at[0].set(_angles_of_rotation(base0 @ rot_z(tau[0])))
        if spine_target is None:
            spine_target = self.init.spine_target
        return Pose(position=position, angles=angles, spine_target=spine_target)

    def standard_orientation(self, pose: Pose) -> Pose:
        """The post-projection (seed 000, DESIGN section 4): every twist no target depends on
        goes back to the standard orientation, with all joint positions unchanged. Twists
        that carry a hinge (the upper arm's, for the elbow) stay; if a reset would still
        break a limit, the solved pose is kept as it is."""
        b, lay = self.body, self.layout
        if not lay.project:
            return pose
        keep = np.zeros(b.n_segments, bool)
        keep[list(lay.keep_twist)] = True
        fk = forward(b, pose)
        deviation = jnp.where(keep, pose.angles[:, 2], 0.0)
        W = fk.R_world_twisted[0]  # kept: the whole body's frame is never projected
        standard = _pose_from_joints(b, fk.joint_positions, W, deviation).angles
        projected = Pose(
            position=pose.position,
            angles=jnp.where(keep[:, None], pose.angles, standard),
            spine_target=pose.spine_target,
        )
        ok = jnp.all(within_limits(b, projected, tol=1e-9))
        return jax.tree.map(lambda a, c: jnp.where(ok, a, c), projected, pose)

    def begin(self) -> tuple[_Unknowns, _Start]:
        """The free variables of the start pose, and its frames."""
        b, lay, init = self.body, self.layout, self.init
        xs, ys, ts = (np.asarray(a, int) for a in (lay.swing_x, lay.swing_y, lay.twist))
        w = self.init_swing
        spine = jnp.zeros(0)
        if lay.spine:
            from ._spine import spine_angles

            total = (
                init.spine_target
                if init.spine_target is not None
                else spine_angles(b, b.spine, init).sum(0)
            )
            spine = _unsquash(total, b.spine.lower.sum(0), b.spine.upper.sum(0))
        x0 = _Unknowns(
            swing_x=_unsquash(w[xs, 0], b.swing_lo[xs, 0], b.swing_hi[xs, 0]),
            swing_y=_unsquash(w[ys, 1], b.swing_lo[ys, 1], b.swing_hi[ys, 1]),
            twist=_unsquash(init.angles[ts, 2], b.twist_lo[ts], b.twist_hi[ts]),
            spine=spine,
            root=jnp.zeros(6 if lay.root else 0),
        )
        R_socket_base, tau = pose_frames(b, init)
        fk = forward_frames(b, R_socket_base, tau, jnp.asarray(init.position))
        return x0, _Start(R_socket_base=R_socket_base, tau=tau, fk=fk)


def _residuals(problem: _Problem, x: _Unknowns, args: tuple[TargetSet, _Unknowns, _Start]):
    """Weighted residuals of all targets (points in m, axes as chord lengths ~ rad), and
    the regularisation toward the start x0 (passed in with the start's frames, so the
    solver's loop does not rebuild them at every evaluation)."""
    targets, x0, start = args
    p, R = problem.effectors(x, start)
    axes = jnp.einsum("kij,kj->ki", R, targets.axis_local)
    reg = jax.tree.map(lambda a, b: jnp.sqrt(REGULARISATION) * (a - b), x, x0)
    reg = eqx.tree_at(lambda r: r.spine, reg, jnp.sqrt(SPINE_PREFERENCE) * reg.spine)
    return (
        targets.point_weight[:, None] * (p - targets.point_xyz),
        targets.axis_weight[:, None] * (axes - targets.axis_direction),
        reg,
    ), (p, axes)


class _Attempt(eqx.Module):
    """One start's solve, or the best so far in the multi-start loop."""

    value: Array  # flat free variables
    cost: Array  # weighted squared target errors
    ok: Array  # every valid target reached
    status: Array  # optimistix.RESULTS index


def _solver(dtype) -> optx.AbstractLeastSquaresSolver:
    """optimistix's Levenberg-Marquardt, chosen by measurement on 1,000 palm targets made by
    FK of random in-limit arm poses (float32, vmapped, 7 unknowns). From the initial posture
    in 30 steps it reached 82 % of them within 1 mm (100 steps: 81 %, the rest are local
    minima); Dogleg 32 % (100 steps: 56 %, it crawls once the arm is redundant), Gauss-Newton
    11 % (32 %). A normal-equations Cholesky solve instead of QR saved 15 % per step and
    reached the same; QR is kept for its margin in float32. The local minima are escaped by
    further starts (`_multistart`)."""
    # float32 cannot resolve changes of 1e-8: its solves would always run to max_steps.
    tol = 1e-8 if jnp.finfo(dtype).bits == 64 else 1e-6
    return optx.LevenbergMarquardt(rtol=tol, atol=tol)


def _target_errors(problem: _Problem, x: _Unknowns, args, ts: TargetSet):
    """Distances of the point targets (m) and angles of the axis targets (rad)."""
    _, (p, axes) = _residuals(problem, x, args)
    cos = jnp.clip(jnp.sum(axes * ts.axis_direction, axis=-1), -1.0, 1.0)
    return jnp.linalg.norm(p - ts.point_xyz, axis=-1), jnp.arccos(cos)


def _multistart(inputs):
    """Solve from starts `first`, `first + 1`, ... until every valid target is reached or
    `starts` are spent; keep the first start that reaches, else the closest reach.

    Start 0 is the initial posture (so a reachable target keeps the most natural posture);
    start k > 0 is a fixed pseudo-random point of the free variables' range (the same for
    every problem: results are reproducible), with the root's placement at init. Most
    targets cost one solve, none more than `starts`. A global function, as optimistix's
    `implicit_jvp` requires.
    """
    problem, args, valid, max_steps, tol_pos, tol_angle, first, starts = inputs
    targets, x0, _ = args
    valid_p, valid_a = valid
    flat0, unravel = ravel_pytree(x0)
    keep_root = np.zeros(flat0.size, bool)
    keep_root[flat0.size - x0.root.size :] = True
    solver = _solver(flat0.dtype)

    def fn(x, args):
        return _residuals(problem, x, args)[0]

    def attempt(k) -> tuple[_Attempt, Array]:
        spread = jax.random.uniform(
            jax.random.fold_in(jax.random.key(0), k), flat0.shape, flat0.dtype, -1.3, 1.3
        )
        seed = jnp.where((k == 0) | keep_root, flat0, spread)
        sol = optx.least_squares(fn, solver, unravel(seed), args, max_steps=max_steps, throw=False)
        err_p, err_a = _target_errors(problem, sol.value, args, targets)
        cost = jnp.sum(targets.point_weight * err_p**2) + jnp.sum(targets.axis_weight * err_a**2)
        ok = jnp.all(jnp.where(valid_p, err_p <= tol_pos, True))
        ok &= jnp.all(jnp.where(valid_a, err_a <= tol_angle, True))
        cost = jnp.where(jnp.isfinite(cost), cost, jnp.inf)
        value = ravel_pytree(sol.value)[0]
        return _Attempt(value, cost, ok, sol.result._value), sol.stats["num_steps"]

    def go_on(carry):
        k, best, _ = carry
        return (k < starts) & ~best.ok

    def step(carry):
        k, best, steps = carry
        this, n = attempt(k)
        take = this.ok | (this.cost < best.cost)  # best is not ok while the loop runs
        best = jax.tree.map(lambda a, b: jnp.where(take, a, b), this, best)
        return k + 1, best, steps + n

    none = _Attempt(flat0, jnp.asarray(jnp.inf, flat0.dtype), jnp.asarray(False), jnp.asarray(0))
    _, best, steps = jax.lax.while_loop(go_on, step, (jnp.asarray(first), none, jnp.asarray(0)))
    return unravel(best.value), (best, steps)


def _stationary(x, _, inputs):
    """The optimality condition the solution satisfies: the cost's gradient is zero."""
    problem, args = inputs[:2]

    def cost(x):
        r = _residuals(problem, x, args)[0]
        return 0.5 * sum(jnp.sum(a**2) for a in jax.tree.leaves(r))

    return jax.grad(cost)(x)


def _solve(
    problem: _Problem,
    targets: TargetSet,
    max_steps: int,
    tol_pos: float | Array,
    tol_angle: float | Array,
    starts: int | Array = 1,
    standard_orientation: bool | Array = True,
    first: int | Array = 0,
):
    """The jitted core: one problem, from starts `first`, ..., `starts - 1` in turn (see
    `_multistart`). Non-finite targets are masked here (weight 0) and reported invalid, so
    a batch never stops on them. Gradients of the solution: the implicit function theorem
    at the kept optimum (optimistix's `implicit_jvp`), forward and reverse mode."""
    ok_p = jnp.all(jnp.isfinite(targets.point_xyz), axis=-1)
    ok_a = jnp.all(jnp.isfinite(targets.axis_direction), axis=-1)
    # Non-finite targets take no part: weight 0 and a harmless value.
    safe = eqx.tree_at(
        lambda t: (t.point_xyz, t.point_weight, t.axis_direction, t.axis_weight),
        targets,
        (
            jnp.where(ok_p[:, None], targets.point_xyz, 0.0),
            jnp.where(ok_p, targets.point_weight, 0.0),
            jnp.where(ok_a[:, None], targets.axis_direction, jnp.array([0.0, 0.0, 1.0])),
            jnp.where(ok_a, targets.axis_weight, 0.0),
        ),
    )
    x0, start = problem.begin()
    args = (safe, x0, start)
    inputs = (problem, args, (ok_p, ok_a), max_steps, tol_pos, tol_angle, first, starts)
    # unwrap: a runtime type-checker's wrapper (jaxtyping's import hook) is a closure.
    sol_value, (best, steps) = implicit_jvp(
        inspect.unwrap(_multistart),
        inspect.unwrap(_stationary),
        inputs,
        frozenset({lx.symmetric_tag}),
        lx.AutoLinearSolver(well_posed=None),
    )
    res_p, res_a = _target_errors(problem, sol_value, args, targets)
    pose = problem.pose(sol_value, start)
    projected = problem.standard_orientation(pose)  # selected at run time: the flag is traced
    pose = jax.tree.map(lambda a, b: jnp.where(standard_orientation, a, b), projected, pose)
    residuals = jnp.concatenate([res_p, res_a])
    valid = jnp.concatenate([ok_p, ok_a])
    reached = valid & jnp.concatenate([res_p <= tol_pos, res_a <= tol_angle])
    residuals = jnp.where(valid, residuals, 0.0)
    return ReachResult(
        pose=pose,
        reached=reached,
        residuals=residuals,
        valid=valid,
        status=best.status,
        steps=steps,
    )


_solve_jit = eqx.filter_jit(_solve)


def make_problem(
    body: Body,
    targets: TargetSet,
    init: Pose | None = None,
    *,
    spine: bool = True,
    free_root: bool = False,
    segments: Sequence[str] | None = None,
) -> _Problem:
    """The fixed part of a reach problem (host side): which unknowns exist and which chain
    the solver walks, from the targets' effectors."""
    init = body.rest_pose() if init is None else init
    points = [int(i) for i in np.asarray(targets.point_index)]
    axes = [int(i) for i in np.asarray(targets.axis_segment)]
    return _Problem(
        body=body,
        layout=_layout(body, points, axes, spine, free_root, segments),
        init=init,
        init_swing=swing_vector(body, init.angles),
    )


def solve_reach(
    body: Body,
    targets: Sequence[Target],
    *,
    init: Pose | None = None,
    spine: bool = True,
    free_root: bool = False,
    segments: Sequence[str] | None = None,
    starts: int = 8,
    standard_orientation: bool = True,
    max_steps: int = 30,
    tol_position: float = 1e-3,
    tol_angle: float = float(np.deg2rad(1.0)),
) -> ReachResult:
    """Reach targets with the body (inverse kinematics, DESIGN section 6).

    Unknowns: the swing vector and twist, within their limits, of every segment between the
    root and the effectors, or of those named in `segments` (a segment no target depends on
    stays as in `init`, and so does one whose ranges are all zero); the spine as its
    Bendspine target 3-vector when the body has a spine database, `spine` is True and the
    spine lies on an effector's chain; the whole body's placement when `free_root`.
    Limits hold exactly by construction (bounded maps of free variables, DESIGN section 6).

    Solved by optimistix (`optx.least_squares` with Levenberg-Marquardt, chosen by
    measurement: see `_solver`) on the weighted residuals (points in metres, axes as chord
    lengths), with a light pull toward `init` that settles redundant postures. Starts are
    tried in turn, `init` first, then fixed pseudo-random points of the limits' range, until
    every target is reached or `starts` are spent; the first start that reaches is kept,
    else the closest reach. Then the standard orientation is restored
    (`standard_orientation`): twists no target depends on return to the standard
    orientation, joint positions unchanged. Unreachable targets give the closest reach with
    `reached` False; a solve that does not converge is a status, never an exception.
    Gradients flow through the solution by the implicit function theorem at the kept
    optimum (w.r.t. targets and the body's dimensions; forward and reverse mode).

    Args:
        body: the body.
        targets: `Target.position(...)`, `Target.axis_direction(...)`, `Target.frame(...)`.
        init: the starting pose (default: the standard position).
        spine, free_root, segments: which unknowns exist (above).
        starts: the most starting points (each costs one solve; on random arm targets the
            first start reaches 82 %, 8 starts 99.9 %: README). An unreachable target
            spends them all.
        standard_orientation: apply the post-projection.
        max_steps: solver steps per start.
        tol_position, tol_angle: what counts as reached (m, rad).

    Returns:
        `ReachResult`: the pose, per target `reached`, `residuals`, `valid`, and the `status`
        (optimistix.RESULTS index of the kept start) and `steps` (over all starts).

    Raises:
        KeyError: an unknown effector or segment name (the message lists the valid ones).
        ValueError: a non-finite or malformed target.
    """
    flat = []
    for t in targets:
        flat.extend(t if isinstance(t, list) else [t])
    for t in flat:
        if isinstance(t.value, jax.core.Tracer):  # under jax.grad: checked by the solve
            continue
        if not np.all(np.isfinite(t.value)):
            raise ValueError(f"solve_reach: target {t.name!r} has a non-finite value {t.value}")
    ts, order = resolve_targets(body, flat)
    problem = make_problem(body, ts, init, spine=spine, free_root=free_root, segments=segments)
    # Only max_steps is static: other settings are traced, so that changing them reuses the
    # compiled solve (a first call costs tens of seconds).
    settings = (tol_position, tol_angle, starts, standard_orientation)
    out = _solve_jit(problem, ts, max_steps, *(jnp.asarray(a) for a in settings))
    back = np.argsort(order)
    return eqx.tree_at(
        lambda r: (r.reached, r.residuals, r.valid),
        out,
        (out.reached[back], out.residuals[back], out.valid[back]),
    )
