"""The spine of Monheit & Badler (1991, seed 004): Bendspine, Movespine, and the body's
vertebrae set from spine angles. The database they read is `Spine` (`_body`), loaded by
`load_spine` (`_loading`).

Angles are (flexion, axial, lateral) per joint, in radians, right-handed about the body's
Y (left), Z (up) and X (forward) axes (DESIGN section 5):

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
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ._body import Body, Pose, Spine
from ._limits import angles_from_swing, swing_vector


class BendResult(eqx.Module):
    """What Bendspine returns: the new joint angles, and per rotation whether the target
    was reached (it lies within the sum of the limits) and by how much it was missed."""

    angles: Float[Array, "n_joint 3"]  # rad
    reached: Bool[Array, "3"]
    shortfall: Float[Array, "3"]  # rad, target - sum(angles): rounding when reached


def _participation_profile(n: int, initiator: Array, spread: float) -> Array:
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
    every joint."""
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
        j_new = j + jnp.where(jnp.abs(total) > 0, remaining * w / safe, 0.0)
        over = active & ((j_new - bound) * s > 0)
        return jnp.where(over, bound, j_new), fixed | over

    j, _ = jax.lax.fori_loop(0, n + 1, step, (j, jnp.zeros(n, bool)))
    return j


def _bend_rotation(j, target, lo, hi, rest, profile, r, active, zero_interpolation):
    """Bendspine in one rotation: joint angles j (n,) to sum to `target`."""
    j = jnp.clip(j, lo, hi)
    current = jnp.sum(j)
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
    return _move(start, target, bound, p, r, active)


def bendspine(
    spine: Spine,
    current: Float[ArrayLike, "n_joint 3"],
    target: Float[ArrayLike, "3"],
    *,
    initiator: int | Int[ArrayLike, ""],
    resistor: int | Int[ArrayLike, ""] | None = None,
    resistance: float | Float[ArrayLike, ""] = 0.0,
    joint_range: tuple[int, int] | Int[ArrayLike, "2"] | None = None,
    zero_interpolation: bool = True,
    spread: float = 3.0,
    tol: float | None = None,
) -> BendResult:
    """Bendspine (seed 004): new joint angles whose sum is `target`.

    Each rotation is computed independently. Moving away from the rest posture ("bending")
    interpolates toward the joint limits, moving back toward it ("unbending") toward the rest
    angles, with global participation P = (target - current) / (limits or rest - current)
    and joint weights w_i = p_i r_i (limit_i - j_i) (or (rest_i - j_i)); the new angles are
    j_i + M w_i / sum(w). Our choices for the seed's p_i and r_i, which it gives in words:

    - p_i = P + (1 - P) f_i, with f_i = exp(-(d_i / spread)^2) (d_i the distance in joints to
      the initiator) capped so that f_i (limit_i - j_i) never exceeds the initiator's room:
      at full participation every weight is 1 (the spine interpolates exactly to its fully
      bent position), and on a fresh bend the initiator moves most, its neighbours less,
      joints far away hardly at all.
    - r_i: see `_resistance_profile`: 1 on the active side, falling linearly to
      1 - resistance at the resistor, 1 - resistance beyond it.

    A joint computed past its limit is set to the limit and the remainder is redistributed,
    so the angles sum exactly to a target within the sum of the limits; beyond that every
    participating joint stops at its limit and `reached` is False.

    Args:
        spine: the database (limits and rest angles).
        current: (n_joint, 3) joint angles (rad), clipped into the limits first.
        target: (3,) the sum of all joint angles wanted (rad).
        initiator: index of the joint where the movement begins (`spine.joint_index`).
        resistor: index of the resisting joint (None: no resistance).
        resistance: 0 (none) to 1 (the resistive region moves only once the active region
            is at its limits).
        joint_range: (from, to) indices, inclusive: the active part; others are frozen.
        zero_interpolation: True: movement across the rest posture goes through it (first
            back to rest, then on toward the other limits). False: only the limits are
            interpolated toward, so sweeping back and forth takes different paths.
        spread: falloff of participation from the initiator, in joints.
        tol: how close (rad, relative to max(1, |target|)) the sum must come to count as
            reached; default 100 n eps of the dtype (2e-4 rad in float32).

    Returns:
        `BendResult`.
    """
    n = spine.n_joints
    current = jnp.asarray(current)
    target = jnp.asarray(target, current.dtype)
    lo_hi = (0, n - 1) if joint_range is None else joint_range
    if resistor is None:
        resistor, resistance = initiator, 0.0
    for name, value in (("initiator", initiator), ("resistor", resistor)):
        if isinstance(value, int) and not 0 <= value < n:
            raise ValueError(f"bendspine: {name} {value} is not a joint index in [0, {n - 1}]")
    if isinstance(lo_hi, tuple) and all(isinstance(x, int) for x in lo_hi):
        if not 0 <= lo_hi[0] <= lo_hi[1] < n:
            raise ValueError(f"bendspine: joint_range {lo_hi} must satisfy 0 <= from <= to < {n}")
        if isinstance(initiator, int) and not lo_hi[0] <= initiator <= lo_hi[1]:
            raise ValueError(
                f"bendspine: the initiator {initiator} lies outside joint_range {lo_hi}"
            )
    lo_hi = jnp.asarray(lo_hi)
    idx = jnp.arange(n)
    active = (idx >= lo_hi[0]) & (idx <= lo_hi[1])
    initiator = jnp.clip(jnp.asarray(initiator), lo_hi[0], lo_hi[1])
    profile = _participation_profile(n, initiator, spread)
    r = _resistance_profile(
        n, initiator, jnp.asarray(resistor), jnp.asarray(resistance, current.dtype)
    )
    bend = jax.vmap(_bend_rotation, in_axes=(1, 0, 1, 1, 1, None, None, None, None), out_axes=1)
    angles = bend(
        current,
        target,
        spine.lower,
        spine.upper,
        spine.rest,
        profile,
        r,
        active,
        zero_interpolation,
    )
    shortfall = target - jnp.sum(angles, axis=0)
    if tol is None:
        tol = 100 * n * float(jnp.finfo(angles.dtype).eps)
    reached = jnp.abs(shortfall) <= tol * jnp.maximum(1.0, jnp.abs(target))
    return BendResult(angles=angles, reached=reached, shortfall=shortfall)


def movespine(
    spine: Spine,
    current: Float[ArrayLike, "n_joint 3"],
    targets: Float[ArrayLike, "n_step 3"],
    *,
    initiator: int | Int[ArrayLike, " n_step"],
    resistor: int | Int[ArrayLike, " n_step"] | None = None,
    resistance: float | Float[ArrayLike, " n_step"] = 0.0,
    joint_range: tuple[int, int] | Int[ArrayLike, "n_step 2"] | None = None,
    zero_interpolation: bool = True,
    spread: float = 3.0,
) -> BendResult:
    """Movespine (seed 004): Bendspine applied to a sequence of targets, each step starting
    from the previous one's angles (jax.lax.scan). Every parameter may be one value or one
    per step (a breathing cycle alternates the joint range of the upper and lower torso).

    Returns a `BendResult` whose fields have a leading step axis.
    """
    targets = jnp.asarray(targets)
    steps = targets.shape[0]
    n = spine.n_joints
    if resistor is None:
        resistor, resistance = initiator, 0.0
    lo_hi = jnp.asarray((0, n - 1) if joint_range is None else joint_range)
    per_step = dict(
        initiator=jnp.broadcast_to(jnp.asarray(initiator), (steps,)),
        resistor=jnp.broadcast_to(jnp.asarray(resistor), (steps,)),
        resistance=jnp.broadcast_to(jnp.asarray(resistance, targets.dtype), (steps,)),
        joint_range=jnp.broadcast_to(lo_hi, (steps, 2)),
    )

    def step(angles, xs):
        target, kw = xs
        out = bendspine(
            spine, angles, target, zero_interpolation=zero_interpolation, spread=spread, **kw
        )
        return out.angles, out

    _, results = jax.lax.scan(step, jnp.asarray(current, targets.dtype), (targets, per_step))
    return results


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
