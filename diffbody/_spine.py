"""The spine of Monheit & Badler (1991, seed 004): Bendspine, Movespine, and the body's
vertebrae set from spine angles. The database they read is `Spine` (`_body`), loaded by
`load_spine` (`_spine_file`).

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


# --- argument checks --------------------------------------------------------------------------


def _is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def _fmt(v: np.ndarray) -> str:
    return repr(tuple(e.item() for e in v)) if v.ndim else repr(v.item())


def _show(x: np.ndarray, bad: np.ndarray) -> str:
    """The first offending value of x (bad: over x's leading axes), with its index."""
    if bad.ndim == 0:
        return _fmt(x)
    k = tuple(int(i) for i in np.argwhere(bad)[0])
    where = f"step {k[0]}" if len(k) == 1 else f"index {list(k)}"
    return f"{_fmt(np.asarray(x[k]))} at {where}"


class _Checker:
    """Argument checks of `fn`: a bad shape or dtype raises ValueError at once (also under
    jit); values are checked on the host when concrete, and otherwise, inside jit, vmap or
    scan, by `eqx.error_if` threaded onto `current` (see `guard`)."""

    def __init__(self, fn: str):
        self.fn = fn
        self.traced: list[tuple[Array, str]] = []

    def error(self, name: str, rule: str, got: str) -> ValueError:
        return ValueError(f"{self.fn}: {name} must {rule}, got {got}")

    def array(self, name, rule, x, kind, shapes):
        """x as an array: a jax array when traced, else a numpy one; `kind` "int" or "real"
        (int or float; bool never), of one of `shapes`."""
        items = x if isinstance(x, (tuple, list)) else (x,)
        if any(isinstance(e, (bool, np.bool_)) for e in items):
            raise self.error(name, rule, repr(x))
        if isinstance(x, (tuple, list)) and any(isinstance(e, jax.Array) for e in x):
            a = jnp.asarray(x)
        elif isinstance(x, jax.Array):
            a = x
        else:
            try:
                a = np.asarray(x)
            except (TypeError, ValueError, OverflowError):
                raise self.error(name, rule, repr(x)) from None
        ok = jnp.issubdtype(a.dtype, jnp.integer) or (
            kind == "real" and jnp.issubdtype(a.dtype, jnp.floating)
        )
        if not ok:
            small = not _is_traced(a) and np.size(a) <= 4
            raise self.error(name, rule, repr(x) if small else f"dtype {a.dtype}")
        if a.shape not in shapes:
            raise self.error(name, rule, f"shape {a.shape}")
        return a

    def values(self, name, rule, a, ok):
        """Require ok(xp, a) everywhere (xp: numpy on the host, jax.numpy when traced)."""
        if _is_traced(a):
            self.traced.append((~jnp.all(ok(jnp, a)), f"{self.fn}: {name} must {rule}"))
            return
        host = np.asarray(a)
        bad = np.asarray(~np.asarray(ok(np, host)))
        if np.any(bad):
            raise self.error(name, rule, _show(host, bad))

    def guard(self, x: Array) -> Array:
        """x carrying the traced checks: every output depends on it, so none is dead code."""
        for pred, msg in self.traced:
            x = eqx.error_if(x, pred, msg)
        return x


def _checked_args(
    fn,
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
    steps,
):
    """Check Bendspine's arguments (`steps`: None for one call, else the number of steps of
    Movespine, whose per-step arguments may also have one value per step) and return them as
    the kernels' arrays: lower, upper, rest, current, target, initiator, resistor, resistance,
    joint_range, spread, tol, zero_interpolation."""
    n = spine.n_joints
    chk = _Checker(fn)
    per = "" if steps is None else f" (one value, or one per step: shape ({steps},))"
    per_pair = "" if steps is None else f" (one pair, or one per step: shape ({steps}, 2))"
    one = [()] if steps is None else [(), (steps,)]

    current = chk.array("current", f"be finite angles of shape ({n}, 3)", current, "real", [(n, 3)])
    if steps is None:
        target = chk.array("target", "have shape (3,)", target, "real", [(3,)])
    else:
        target = chk.array("targets", "have shape (n_step, 3)", target, "real", [(steps, 3)])
    dtypes = [
        a.dtype for a in (current, target, spine.lower) if jnp.issubdtype(a.dtype, jnp.floating)
    ]
    dtype = jax.dtypes.canonicalize_dtype(np.result_type(*dtypes))
    chk.values(
        "current", f"be finite angles of shape ({n}, 3)", current, lambda xp, a: xp.isfinite(a)
    )

    index_rule = f"be an integer joint index in [0, {n - 1}]{per}"
    initiator = chk.array("initiator", index_rule, initiator, "int", one)
    chk.values("initiator", index_rule, initiator, lambda xp, a: (a >= 0) & (a <= n - 1))
    resistance_rule = f"lie in [0, 1]{per}"
    resistance = chk.array("resistance", resistance_rule, resistance, "real", one)
    chk.values("resistance", resistance_rule, resistance, lambda xp, a: (a >= 0) & (a <= 1))
    if resistor is None:
        resistor, resistance = initiator, np.zeros(())
    else:
        resistor = chk.array("resistor", index_rule, resistor, "int", one)
        chk.values("resistor", index_rule, resistor, lambda xp, a: (a >= 0) & (a <= n - 1))

    range_rule = f"be two integers 0 <= from <= to <= {n - 1}{per_pair}"
    if joint_range is None:
        joint_range = np.asarray((0, n - 1))
    shapes = [(2,)] if steps is None else [(2,), (steps, 2)]
    joint_range = chk.array("joint_range", range_rule, joint_range, "int", shapes)
    chk.values(
        "joint_range",
        range_rule,
        joint_range,
        lambda xp, a: (a[..., 0] >= 0) & (a[..., 0] <= a[..., 1]) & (a[..., 1] <= n - 1),
    )
    if _is_traced(initiator) or _is_traced(joint_range):
        inside = (initiator >= joint_range[..., 0]) & (initiator <= joint_range[..., 1])
        chk.traced.append((~jnp.all(inside), f"{fn}: initiator must lie in joint_range"))
    else:
        i_h, r_h = np.asarray(initiator), np.asarray(joint_range)
        lead = np.broadcast_shapes(i_h.shape, r_h.shape[:-1])  # () or (steps,)
        i_h, r_h = np.broadcast_to(i_h, lead), np.broadcast_to(r_h, lead + (2,))
        bad = (i_h < r_h[..., 0]) | (i_h > r_h[..., 1])
        if np.any(bad):
            k = tuple(np.argwhere(bad)[0])
            at = f" at step {k[0]}" if k else ""
            raise chk.error("initiator", f"lie in joint_range {r_h[k].tolist()}", f"{i_h[k]}{at}")

    spread = chk.array("spread", "be finite and > 0", spread, "real", [()])
    chk.values("spread", "be finite and > 0", spread, lambda xp, a: xp.isfinite(a) & (a > 0))
    if tol is None:
        tol = 100 * n * float(jnp.finfo(dtype).eps)
    tol = chk.array("tol", "be finite and > 0 (or None)", tol, "real", [()])
    chk.values("tol", "be finite and > 0 (or None)", tol, lambda xp, a: xp.isfinite(a) & (a > 0))

    z = zero_interpolation
    if isinstance(z, (bool, np.bool_)):
        z = np.asarray(z)
    elif not (isinstance(z, (jax.Array, np.ndarray)) and z.dtype == bool and z.shape == ()):
        raise chk.error("zero_interpolation", "be a bool", repr(zero_interpolation))

    current = chk.guard(jnp.asarray(current, dtype))
    if steps is not None:
        lead = (steps,)
        initiator = jnp.broadcast_to(jnp.asarray(initiator), lead)
        resistor = jnp.broadcast_to(jnp.asarray(resistor), lead)
        resistance = jnp.broadcast_to(jnp.asarray(resistance), lead)
        joint_range = jnp.broadcast_to(jnp.asarray(joint_range), lead + (2,))
    # Fixed dtypes: Python, numpy and jax scalars all reach the kernel as the same arrays, so
    # that it compiles once.
    initiator, resistor, joint_range = (
        jnp.asarray(a, jnp.int32) for a in (initiator, resistor, joint_range)
    )
    return (
        jnp.asarray(spine.lower, dtype),
        jnp.asarray(spine.upper, dtype),
        jnp.asarray(spine.rest, dtype),
        current,
        jnp.asarray(target, dtype),
        initiator,
        resistor,
        jnp.asarray(resistance, dtype),
        joint_range,
        jnp.asarray(spread, dtype),
        jnp.asarray(tol, dtype),
        jnp.asarray(z, bool),
    )


def bendspine(
    spine: Spine,
    # Loose annotations: shapes, dtypes and ranges are checked, and reported, by `_checked_args`.
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
    participating joint stops at its limit and `reached` is False. Unbending, the joints on
    the far side of their rest angle (whose weights would have the other sign) return by the
    share P of their way; the others make up the target by the formula.

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
    args = _checked_args(
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
    args = _checked_args(
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
