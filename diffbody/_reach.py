"""Reach: inverse kinematics with optimistix (DESIGN section 6).

Targets put named points of the body (joints, sphere features, the center of gravity) on
positions and segment axes along directions. The unknowns are every movable segment's swing
vector and twist, the spine as its Bendspine target 3-vector (so the 54 vertebra angles move
as a spine), and optionally the whole body's placement. Joint limits hold exactly: each
unknown is a bounded map of a free variable (a logistic squash into [lo, hi], the swing then
pulled radially into its cone), so the solver cannot leave the admissible set.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ._body import Body, Pose
from ._kinematics import (
    exp_swing,
    forward_frames,
    socket_frames,
    socket_frames_from_swing,
    spine_deviation,
)
from ._limits import angles_from_swing, swing_vector
from ._posture import _angles_of_rotation
from ._rotations import matmul3, rot_z, skew

# Regularisation toward the initial posture, per unit of the free variables: it resolves
# redundancy (a whole arm plus a spine reach one point) without moving reachable targets by
# more than micrometres.
REGULARISATION = 1e-8


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
    """Which pose quantities are unknowns (static)."""

    swing_x: tuple[int, ...]  # segments whose w_x is free
    swing_y: tuple[int, ...]
    twist: tuple[int, ...]
    spine: bool
    root: bool


def _layout(body: Body, use_spine: bool, free_root: bool) -> _Layout:
    spine_segs = set(body.spine.segment_names) if (use_spine and body.spine) else set()
    lo, hi = np.asarray(body.swing_lo), np.asarray(body.swing_hi)
    tlo, thi = np.asarray(body.twist_lo), np.asarray(body.twist_hi)
    movable = [i for i, n in enumerate(body.segment_names) if i > 0 and n not in spine_segs]
    return _Layout(
        swing_x=tuple(i for i in movable if hi[i, 0] > lo[i, 0]),
        swing_y=tuple(i for i in movable if hi[i, 1] > lo[i, 1]),
        twist=tuple(i for i in movable if thi[i] > tlo[i]),
        spine=bool(spine_segs),
        root=free_root,
    )


def _squash(u, lo, hi):
    return lo + (hi - lo) * jax.nn.sigmoid(u)


def _unsquash(v, lo, hi):
    # Start a little inside the range: the squash is flat at its bounds.
    f = jnp.clip((v - lo) / jnp.where(hi > lo, hi - lo, 1.0), 0.03, 0.97)
    return jnp.log(f) - jnp.log1p(-f)


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


class _Problem(eqx.Module):
    """Everything fixed during one solve: the body, which unknowns exist, the start."""

    body: Body
    layout: _Layout = eqx.field(static=True)
    init: Pose
    init_swing: Array  # (n_seg, 2)

    def state(self, x: _Unknowns):
        """Swing vectors, twists, the whole body's base frame, position and spine target of
        the unknowns: box squash, then the radial pull into the cone, so every limit holds
        exactly."""
        b, lay = self.body, self.layout
        xs, ys, ts = (np.asarray(a, int) for a in (lay.swing_x, lay.swing_y, lay.twist))
        w = self.init_swing
        w = w.at[xs, 0].set(_squash(x.swing_x, b.swing_lo[xs, 0], b.swing_hi[xs, 0]))
        w = w.at[ys, 1].set(_squash(x.swing_y, b.swing_lo[ys, 1], b.swing_hi[ys, 1]))
        norm2 = jnp.sum(w * w, axis=-1)
        over = norm2 > b.swing_max**2
        safe = jnp.where(over, norm2, 1.0)
        w = w * jnp.where(over, b.swing_max / jnp.sqrt(safe), 1.0)[:, None]
        tau = self.init.angles[:, 2].at[ts].set(_squash(x.twist, b.twist_lo[ts], b.twist_hi[ts]))
        base0 = socket_frames(b, self.init.angles[:1], np.asarray([0]))[0]
        position = self.init.position
        if lay.root:
            base0 = _rotvec_to_matrix(x.root[3:]) @ base0
            position = position + x.root[:3]
        spine_target = None
        if lay.spine:
            spine_target = _squash(x.spine, b.spine.lower.sum(0), b.spine.upper.sum(0))
        return w, tau, base0, position, spine_target

    def kinematics(self, x: _Unknowns):
        """Forward kinematics straight from the swing vectors (smooth at the poles)."""
        b = self.body
        w, tau, base0, position, spine_target = self.state(x)
        R = socket_frames_from_swing(b, w).at[0].set(base0)
        if spine_target is not None:
            seg, w_sp, t_sp = spine_deviation(b, spine_target)
            R = R.at[seg].set(matmul3(b.R_socket_rest[seg], exp_swing(w_sp)))
            tau = tau.at[seg].set(t_sp)
        return forward_frames(b, R, tau, position)

    def pose(self, x: _Unknowns) -> Pose:
        """The public pose of the unknowns (theta, phi, tau rows; the spine as its target)."""
        w, tau, base0, position, spine_target = self.state(x)
        angles = angles_from_swing(self.body, w, tau)
        angles = angles.at[0].set(_angles_of_rotation(base0 @ rot_z(tau[0])))
        return Pose(position=position, angles=angles, spine_target=spine_target)

    def start(self) -> _Unknowns:
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
        return _Unknowns(
            swing_x=_unsquash(w[xs, 0], b.swing_lo[xs, 0], b.swing_hi[xs, 0]),
            swing_y=_unsquash(w[ys, 1], b.swing_lo[ys, 1], b.swing_hi[ys, 1]),
            twist=_unsquash(init.angles[ts, 2], b.twist_lo[ts], b.twist_hi[ts]),
            spine=spine,
            root=jnp.zeros(6 if lay.root else 0),
        )


def _residuals(problem: _Problem, x: _Unknowns, args: tuple[TargetSet, _Unknowns]):
    """Weighted residuals of all targets (points in m, axes as chord lengths ~ rad), and
    the regularisation toward the start x0 (passed in, so the solver loop does not rebuild
    it at every evaluation)."""
    targets, x0 = args
    fk = problem.kinematics(x)
    points = jnp.concatenate([fk.joint_positions, fk.feature_points, fk.center_of_gravity[None]])
    p = points[targets.point_index]
    axes = jnp.einsum("kij,kj->ki", fk.R_world_twisted[targets.axis_segment], targets.axis_local)
    reg = jax.tree.map(lambda a, b: jnp.sqrt(REGULARISATION) * (a - b), x, x0)
    return (
        targets.point_weight[:, None] * (p - targets.point_xyz),
        targets.axis_weight[:, None] * (axes - targets.axis_direction),
        reg,
    ), (p, axes)


def _solve(
    problem: _Problem,
    targets: TargetSet,
    max_steps: int,
    tol_pos: float,
    tol_angle: float,
):
    """The jitted core: one problem. Non-finite targets are masked here (weight 0) and
    reported invalid, so a batch never stops on them."""
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

    def fn(x, args):
        return _residuals(problem, x, args)[0]

    # Measured on FK-generated palm targets of the default body (x64, 100 steps): Dogleg
    # reached 12 of 12, Gauss-Newton 6, Levenberg-Marquardt crawled (its damping is badly
    # scaled for the squashed unknowns): Dogleg's trust region is the robust choice here.
    solver = optx.Dogleg(rtol=1e-10, atol=1e-10)
    x0 = problem.start()
    sol = optx.least_squares(fn, solver, x0, args=(safe, x0), max_steps=max_steps, throw=False)
    pose = problem.pose(sol.value)
    _, (p, axes) = _residuals(problem, sol.value, (safe, x0))
    res_p = jnp.linalg.norm(p - targets.point_xyz, axis=-1)
    cos = jnp.clip(jnp.sum(axes * targets.axis_direction, axis=-1), -1.0, 1.0)
    res_a = jnp.arccos(cos)
    residuals = jnp.concatenate([res_p, res_a])
    valid = jnp.concatenate([ok_p, ok_a])
    reached = valid & jnp.concatenate([res_p <= tol_pos, res_a <= tol_angle])
    residuals = jnp.where(valid, residuals, 0.0)
    return ReachResult(
        pose=pose,
        reached=reached,
        residuals=residuals,
        valid=valid,
        status=sol.result._value,
        steps=sol.stats["num_steps"],
    )


_solve_jit = eqx.filter_jit(_solve)


def make_problem(
    body: Body, init: Pose | None = None, *, spine: bool = True, free_root: bool = False
) -> _Problem:
    """The fixed part of a reach problem (host side)."""
    init = body.rest_pose() if init is None else init
    return _Problem(
        body=body,
        layout=_layout(body, spine, free_root),
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
    max_steps: int = 100,
    tol_position: float = 1e-3,
    tol_angle: float = float(np.deg2rad(1.0)),
) -> ReachResult:
    """Reach targets with the body (inverse kinematics, DESIGN section 6).

    Unknowns: every segment's swing vector and twist within its limits (segments whose
    ranges are all zero stay put), the spine as its Bendspine target 3-vector when the body
    has a spine database and `spine` is True, and the whole body's placement when
    `free_root` (otherwise it stays as in `init`). Solved by optimistix's
    Dogleg on the weighted residuals (points in metres, axes as chord lengths),
    with a light pull toward `init` that settles redundant postures. Limits hold exactly
    by construction. Unreachable targets give the closest reach with `reached` False; a
    solve that does not converge is a status, never an exception.

    Args:
        body: the body.
        targets: `Target.position(...)`, `Target.axis_direction(...)`, `Target.frame(...)`.
        init: the starting pose (default: the standard position).
        tol_position, tol_angle: what counts as reached (m, rad).

    Raises:
        KeyError: an unknown effector name (the message lists the valid ones).
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
    problem = make_problem(body, init, spine=spine, free_root=free_root)
    out = _solve_jit(problem, ts, max_steps, tol_position, tol_angle)
    back = np.argsort(order)
    return eqx.tree_at(
        lambda r: (r.reached, r.residuals, r.valid),
        out,
        (out.reached[back], out.residuals[back], out.valid[back]),
    )
