"""The spine of Monheit & Badler (1991, seed 004): Bendspine, Movespine, and the body's
vertebrae set from spine angles, on a `Spine` database (`_body`). Arguments are checked by
`_spine_checks`.

Angles are (flexion, axial, lateral) per joint, in radians, right-handed about the body's
Y (left), Z (up) and X (forward) axes (docs/design.md, section 5):

- flexion > 0 bends forward (extension < 0),
- axial > 0 turns to the left,
- lateral > 0 bends to the right.

Joints run from the top, C7-T1 (it moves the neck), down to L5-S1 (it moves L5); joint k
moves the vertebra above it. Angles are absolute: the standing posture is the database's
rest angles (thoracic kyphosis, lumbar lordosis), and the target of Bendspine is the sum of
all joint angles, as in the seed.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from ._body import Body, Pose, Spine
from ._limits import angles_from_swing, swing_vector
from ._spine_checks import checked_args


class BendResult(eqx.Module):
    """What Bendspine returns: the new joint angles, and per rotation whether the target
    was reached (it is finite and within what the active joints can reach) and by how much it
    was missed."""

    angles: Float[Array, "n_joint 3"]  # rad
    reached: Bool[Array, "3"]
    # rad, target - sum(angles): rounding when reached; inf or NaN for a non-finite target
    shortfall: Float[Array, "3"]


# How far beyond what the active joints can reach a target is clipped to: any target past the
# limits bends the joints to them, so this only keeps inf out of the arithmetic.
_REACH_MARGIN = 1.0  # rad


def _participation_profile(n: int, initiator: Array, spread: Array) -> Array:
    """exp(-(d / spread)^2) of the distance d (in joints) to the initiator."""
    d = jnp.arange(n) - initiator
    return jnp.exp(-((d / spread) ** 2))


def _resistance_profile(n: int, initiator: Array, resistor: Array, resistance: Array) -> Array:
    """r_i (seed 004, "Resistance"). The spine is split at the resistor; the side holding the
    initiator is active. Joints from the resistor on, away from the initiator, are resistive:
    r = 1 - resistance. Joints between the initiator and the resistor lose activity linearly
    from 1 at the initiator to 1 - resistance at the resistor. The rest of the active side has
    r = 1. With the resistor at the initiator there is no resistive side: r = 1."""
    i = jnp.arange(n)
    side = jnp.sign(resistor - initiator)
    t = jnp.clip((i - initiator) * side / jnp.maximum(jnp.abs(resistor - initiator), 1), 0.0, 1.0)
    return jnp.where(side == 0, 1.0, 1.0 - resistance * t)


def _move(j, target, bound, p, r, active):
    """Move the active joints toward `bound` so that sum(j) = target (seed 004, "Calculation
    of joint positions": j* = j + M w / sum w with w = p r (bound - j)). A joint computed past
    its bound is set to it and the remainder goes to the others, again by their weights; when
    every joint with a non-zero weight is at its bound and some remains, the resistive region
    takes part (resistance does not freeze joints). Repeats n + 1 times, enough to settle
    every joint. Every active bound - j must share the sign of target - sum(j): each joint then
    moves only toward its bound and stops there."""
    n = j.shape[0]
    s = jnp.sign(target - jnp.sum(j))

    def step(_, carry):
        j, fixed = carry
        remaining = target - jnp.sum(j)
        room = jnp.where(active & ~fixed, bound - j, 0.0)
        w, w_free = p * r * room, p * room
        total, total_free = jnp.sum(w), jnp.sum(w_free)
        use_free = jnp.abs(total) <= 1e-300
        w = jnp.where(use_free, w_free, w)
        total = jnp.where(use_free, total_free, total)
        safe = jnp.where(jnp.abs(total) > 0, total, 1.0)
        # w / total first: each share lies in [0, 1] (the rooms share one sign), so a tiny
        # total cannot overflow or underflow the product.
        j_new = j + jnp.where(jnp.abs(total) > 0, remaining * (w / safe), 0.0)
        over = active & ((j_new - bound) * s > 0)
        return jnp.where(over, bound, j_new), fixed | over

    j, _ = jax.lax.fori_loop(0, n + 1, step, (j, jnp.zeros(n, bool)))
    return j


def _bend_rotation(j, target, lo, hi, rest, profile, r, active, zero_interpolation):
    """Bendspine in one rotation: joint angles j (n,) to sum to `target`."""
    j = jnp.clip(j, lo, hi)
    current = jnp.sum(j)
    # Past what the active joints can reach every target gives the same angles (those joints
    # at their limits): clipping it there, with a margin that keeps it out of reach, keeps +-inf
    # out of the arithmetic. A NaN target asks for no movement.
    reach_lo = jnp.sum(jnp.where(active, lo, j))
    reach_hi = jnp.sum(jnp.where(active, hi, j))
    target = jnp.where(
        jnp.isnan(target),
        current,
        jnp.clip(target, reach_lo - _REACH_MARGIN, reach_hi + _REACH_MARGIN),
    )
    rest_j = jnp.where(active, rest, j)
    rest_sum = jnp.sum(rest_j)
    M = target - current
    toward_rest = M * (rest_sum - current) > 0
    within_rest = jnp.abs(M) <= jnp.abs(rest_sum - current)
    unbending = zero_interpolation & toward_rest & within_rest
    # With zero interpolation a target beyond the rest position is reached through it: every
    # active joint first returns to rest, then bends on from there.
    through_rest = zero_interpolation & toward_rest & ~within_rest
    start = jnp.where(through_rest, rest_j, j)
    start_sum = jnp.sum(start)
    M = target - start_sum
    limit = jnp.where(M >= 0, hi, lo)
    bound = jnp.where(unbending, rest_j, jnp.where(active, limit, start))
    room_total = jnp.sum(bound) - start_sum
    # Global participation P (seed 004): the share of the available movement asked for.
    safe_room = jnp.where(room_total == 0, 1.0, room_total)
    P = jnp.clip(jnp.where(room_total == 0, 1.0, M / safe_room), 0.0, 1.0)
    room = jnp.abs(bound - start)
    room_init = jnp.sum(jnp.where(profile == 1.0, room, 0.0))
    # p_i = P + (1 - P) f_i: 1 everywhere at full participation; at small participation the
    # initiator's weight dominates, falling off with distance, and no joint's weight exceeds
    # the initiator's (f_i is capped by the initiator's room over the joint's room).
    f = profile * jnp.minimum(1.0, room_init / jnp.maximum(room, 1e-12))
    p = P + (1.0 - P) * f
    # Unbending, joints on the far side of their rest angle return against the target: their
    # weights w_i would have the other sign, and the formula would push some joints away from
    # rest, past their limits. They return by P, the share of the way to rest asked for; the
    # others make up the rest of the target by the formula. At the rest sum (P = 1) every
    # joint is at rest.
    step = bound - start
    opposer = active & (step * M < 0)
    back = P * jnp.sum(jnp.where(opposer, step, 0.0))
    moved = _move(start, target - back, bound, p, r, active & ~opposer)
    return jnp.where(opposer, start + P * step, moved)


@jax.jit
def _bend_kernel(
    lower,
    upper,
    rest,
    current,
    target,
    initiator,
    resistor,
    resistance,
    lo_hi,
    spread,
    tol,
    zero_interpolation,
):
    """Bendspine on checked arrays (see `bendspine`); compiled once per shape and dtype, and
    inlined under an outer transformation."""
    n = current.shape[0]
    idx = jnp.arange(n)
    active = (idx >= lo_hi[0]) & (idx <= lo_hi[1])
    # Joint distances are integers, whose ratios jax computes in the default float: back to
    # the angles' dtype (float32 angles with float64 enabled).
    profile = _participation_profile(n, initiator, spread).astype(current.dtype)
    r = _resistance_profile(n, initiator, resistor, resistance).astype(current.dtype)
    bend = jax.vmap(_bend_rotation, in_axes=(1, 0, 1, 1, 1, None, None, None, None), out_axes=1)
    angles = bend(current, target, lower, upper, rest, profile, r, active, zero_interpolation)
    shortfall = target - jnp.sum(angles, axis=0)
    # inf - sum(angles) is inf, and inf <= tol * inf: only a finite target can be reached.
    reached = jnp.isfinite(target) & (jnp.abs(shortfall) <= tol * jnp.maximum(1.0, jnp.abs(target)))
    return BendResult(angles=angles, reached=reached, shortfall=shortfall)


@jax.jit
def _move_kernel(
    lower,
    upper,
    rest,
    current,
    targets,
    initiator,
    resistor,
    resistance,
    lo_hi,
    spread,
    tol,
    zero_interpolation,
):
    """Movespine on checked arrays, one value per step."""

    def step(angles, xs):
        target, i, rr, res, rng = xs
        out = _bend_kernel(
            lower, upper, rest, angles, target, i, rr, res, rng, spread, tol, zero_interpolation
        )
        return out.angles, out

    xs = (targets, initiator, resistor, resistance, lo_hi)
    _, results = jax.lax.scan(step, current, xs)
    return results


# --- the public calls -------------------------------------------------------------------------


def bendspine(
    spine: Spine,
    # Loose annotations: shapes, dtypes and ranges are checked, and reported, by `checked_args`.
    current: ArrayLike,
    target: ArrayLike,
    *,
    initiator: ArrayLike,
    resistor: ArrayLike | None = None,
    resistance: ArrayLike = 0.0,
    joint_range: tuple | list | ArrayLike | None = None,
    zero_interpolation: ArrayLike = True,
    spread: ArrayLike = 3.0,
    tol: ArrayLike | None = None,
) -> BendResult:
    """Bendspine (seed 004; docs/design.md, section 5): new joint angles whose sum is `target`.

    Each rotation is computed independently. Bending (away from the rest posture) moves the
    active joints toward their limits, unbending toward their rest angles, each joint by its
    weight w_i = p_i r_i (bound_i - j_i): participation p_i is 1 everywhere when the whole
    movement is asked for and, on a small bend, largest at the initiator and falling off
    over `spread` joints; r_i falls to 1 - resistance at the resistor (`_resistance_profile`).
    A joint computed past its limit stops there and the rest goes to the others, so a target
    within the limits is met exactly; beyond them every active joint stops at its limit and
    `reached` is False.

    Arguments out of range raise ValueError; when traced (under jit, vmap, scan) their values
    are checked by `equinox.error_if`, which raises at run time.

    Args:
        spine: the database (limits and rest angles).
        current: (n_joint, 3) finite joint angles (rad), clipped into the limits first.
        target: (3,) the sum of all joint angles wanted (rad). A component may be non-finite:
            +inf (-inf) bends that rotation's active joints to their upper (lower) limits, as
            a huge finite target does; NaN leaves that rotation at the clipped current angles.
            Such components are never `reached`; their `shortfall` is inf or NaN.
        initiator: integer index in [0, n_joint - 1] of the joint where the movement begins
            (`spine.joint_index`), inside `joint_range`.
        resistor: integer index in [0, n_joint - 1] of the resisting joint (None: no
            resistance, and `resistance` is ignored).
        resistance: in [0, 1]: 0 (none) to 1 (the resistive region moves only once the active
            region is at its limits).
        joint_range: (from, to) integer indices, 0 <= from <= to <= n_joint - 1, inclusive:
            the active part; the others stay at their (clipped) current angles.
        zero_interpolation: a bool. True: movement across the rest posture goes through it
            (first back to rest, then on toward the other limits). False: only the limits are
            interpolated toward, so sweeping back and forth takes different paths.
        spread: finite, > 0: falloff of participation from the initiator, in joints.
        tol: finite, > 0: how close (rad, relative to max(1, |target|)) the sum must come to
            count as reached; None: 100 n eps of the dtype (4e-13 rad in float64, 2e-4 rad in
            float32).

    Returns:
        `BendResult`.
    """
    args = checked_args(
        "bendspine",
        spine,
        current,
        target,
        initiator,
        resistor,
        resistance,
        joint_range,
        zero_interpolation,
        spread,
        tol,
        None,
    )
    return _bend_kernel(*args)


def bend_from_rest(spine: Spine, target: Float[Array, "3"]) -> BendResult:
    """`bendspine(spine, spine.rest, target, initiator=spine.initiator)` with every other
    option at its default, for `forward` and the solvers. Nothing is checked: the rest
    angles and limits were checked when the database was loaded and any target is valid. A
    traced check would be a host callback (`eqx.error_if`), and XLA keeps no program with
    one in its persistent cache, so every process would compile each solve anew."""
    n = spine.n_joints
    dtype = jnp.result_type(spine.rest.dtype, target)
    i = jnp.asarray(spine.initiator, jnp.int32)
    return _bend_kernel(
        jnp.asarray(spine.lower, dtype),
        jnp.asarray(spine.upper, dtype),
        jnp.asarray(spine.rest, dtype),
        jnp.asarray(spine.rest, dtype),
        jnp.asarray(target, dtype),
        i,
        i,  # no resistor: resistance 0
        jnp.zeros((), dtype),
        jnp.asarray((0, n - 1), jnp.int32),
        jnp.asarray(3.0, dtype),  # bendspine's default spread
        jnp.asarray(100 * n * float(jnp.finfo(dtype).eps), dtype),  # its default tol
        jnp.asarray(True),
    )


def movespine(
    spine: Spine,
    current: ArrayLike,
    targets: ArrayLike,
    *,
    initiator: ArrayLike,
    resistor: ArrayLike | None = None,
    resistance: ArrayLike = 0.0,
    joint_range: tuple | list | ArrayLike | None = None,
    zero_interpolation: ArrayLike = True,
    spread: ArrayLike = 3.0,
) -> BendResult:
    """Movespine (seed 004): Bendspine applied to a sequence of targets, each step starting
    from the previous one's angles (jax.lax.scan). `initiator`, `resistor`, `resistance` and
    `joint_range` may be one value or one per step (shape (n_step,), joint_range
    (n_step, 2)): a breathing cycle alternates the joint range of the upper and lower torso.
    Ranges and errors as for `bendspine`.

    Returns a `BendResult` whose fields have a leading step axis.
    """
    steps = np.shape(targets)[0] if np.ndim(targets) == 2 else None
    if steps is None:
        raise ValueError(f"movespine: targets must have shape (n_step, 3), got {np.shape(targets)}")
    args = checked_args(
        "movespine",
        spine,
        current,
        targets,
        initiator,
        resistor,
        resistance,
        joint_range,
        zero_interpolation,
        spread,
        None,
        steps,
    )
    return _move_kernel(*args)


# --- the body's vertebrae ---------------------------------------------------------------------


def _segments(body: Body, spine: Spine) -> np.ndarray:
    return np.asarray([body.segment_index(s) for s in spine.segment_names])


def spine_angles(body: Body, spine: Spine, pose: Pose) -> Float[Array, "n_joint 3"]:
    """The spine state (flexion, axial, lateral) of a pose (rad): for the segment each joint
    moves, its swing vector (w_y is flexion, w_x lateral bending) and twist (axial rotation)
    are the deviation from the rest angles, since the body's standard position is the spine
    at rest."""
    seg = _segments(body, spine)
    w = swing_vector(body, pose.angles)[seg]
    dev = jnp.stack([w[:, 1], pose.angles[seg, 2], w[:, 0]], axis=-1)
    return spine.rest + dev


def with_spine_angles(
    body: Body, spine: Spine, pose: Pose, angles: Float[ArrayLike, "n_joint 3"]
) -> Pose:
    """The pose with its vertebrae (and neck) set from spine angles (rad)."""
    seg = _segments(body, spine)
    dev = jnp.asarray(angles) - spine.rest
    n = body.n_segments
    swing = jnp.zeros((n, 2), dev.dtype).at[seg].set(jnp.stack([dev[:, 2], dev[:, 0]], axis=-1))
    twist = jnp.zeros(n, dev.dtype).at[seg].set(dev[:, 1])
    rows = angles_from_swing(body, swing, twist)[seg]
    return Pose(position=pose.position, angles=pose.angles.at[seg].set(rows))


def bend_pose(
    body: Body, spine: Spine, pose: Pose, target: Float[ArrayLike, "3"], **bendspine_options
) -> tuple[Pose, BendResult]:
    """Bend the body's spine to a Bendspine target (rad, the sum of all joint angles) from
    the pose's current spine state; `bendspine_options` as for `bendspine`."""
    out = bendspine(spine, spine_angles(body, spine, pose), target, **bendspine_options)
    return with_spine_angles(body, spine, pose, out.angles), out
