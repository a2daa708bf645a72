"""The phases of a reach solve and the drivers that try their starts (docs/design.md,
section 6).

A solve runs in phases, as a person reaches: first the limbs (every unknown below the
trunk: clavicle, arm, hand; thigh, shank, foot; the head on the neck), with the spine, the
pelvis and the whole body held as in `init`; only if that misses, the trunk joins (the
spine as its Bendspine target, the root's placement when free), starting from the limbs'
closest reach. Within a phase, starts are tried in turn (the closed-form limb start or the
start pose first, then the fixed points of `_starts`), each in rounds (`_attempt`), until
every target is reached, unless a target lies out of the phase's reach (`out_of_reach`),
which decides up front that no start can reach it: then the phase tries its first start
only (its answer is the next phase's start). With concrete inputs the host drives phases,
starts and rounds (`solve_host`), so only what a target needs is run; under a JAX transformation
(`solve_traced`) the starts run side by side, each one uninterrupted solve, and the kept
attempt is selected with `jnp.where`.
"""

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._body import Body, Pose
from .._body_cache import RANGES, BodyCache
from .._device_arrays import device_array
from .._kinematics import Links
from .._programs import compiled, is_traced
from .._spine import spine_angles
from ..problem._problem import make_problem, stiffness_of
from ..problem._targets import TargetSet
from ..problem._tree import padded_targets, tree_layout
from ..problem._unknowns import Layout, make_layout
from ._attempt import (
    Attempt,
    Settings,
    assess,
    attempt_round,
    better,
    no_gradient,
    phase_steps,
    round_caps,
    solve_free,
)
from ._limb_groups import joined, limb_groups
from ._plans import fits_tree, make_limb_plan, make_plan, padded_errors
from ._reach_bounds import beyond_bound, host_links, out_of_reach, rest_links


def is_none(x) -> bool:
    """Whether x is None: the `is_leaf` that lets `eqx.tree_at` fill an empty field."""
    return x is None


# --- the phases -------------------------------------------------------------------------
def phase_layouts(
    body: Body,
    phase_targets: Sequence[TargetSet],
    *,
    spine: bool,
    free_root: bool,
    segments: Sequence[str] | None,
    stand: bool = False,
) -> list[Layout]:
    """The layouts of the phases: the limbs alone, then everything (one layout when the two
    coincide or the limbs have no unknown on a target's chain). `phase_targets`: the
    targets of the limbs' phase and of the trunk's (their constraints decide what is read);
    `stand`: the trunk's phase stands on its feet (the root's placement and the legs free).
    Cached per body structure and limits (host work of milliseconds, on every call
    otherwise)."""
    args = (body, tuple(phase_targets), spine, free_root, segments, stand)
    if is_traced([getattr(body, name) for name in RANGES]):
        return _phase_layouts(*args)
    extra = (
        tuple((ts.point_index, ts.axis_segment, _reads(ts)) for ts in phase_targets),
        spine,
        free_root,
        None if segments is None else tuple(segments),
        stand,
    )
    return _LAYOUTS.get(body, extra, lambda: _phase_layouts(*args))


_LAYOUTS = BodyCache(RANGES, size=256)


def _reads(ts: TargetSet) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The segments a target set's constraints read, and its feet."""
    c = ts.constraints
    return ((), ()) if c is None else (c.segments, c.feet)


def _phase_layouts(body, phase_targets, spine, free_root, segments, stand) -> list[Layout]:
    """`phase_layouts`, uncached."""
    first, last = phase_targets[0], phase_targets[-1]
    points, axes = first.point_index, first.axis_segment
    movable = set(range(body.n_segments))
    if segments is not None:
        movable = {body.segment_index(name) for name in segments}
    read, feet = _reads(last)
    full = make_layout(body, points, axes, movable, spine, free_root or stand, read, feet)
    read, feet = _reads(first)
    limbs = make_layout(body, points, axes, movable - body.trunk, False, False, read, feet)
    if limbs.n_free == 0 or limbs.n_free == full.n_free:
        return [full]
    return [limbs, full]


def phase_plan(
    body: Body,
    layouts: list[Layout],
    phase: int,
    init: Pose,
    xyz: ArrayLike,
    max_steps: int,
    links: Links | None = None,
) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """For phase `phase` from `init`: per point target whether it is beyond the reach bound
    (reported) and out of reach (no further start), and the round caps of a start out of
    reach: every round, so that a limb reaching for what it cannot reach ends at its closest
    reach, where the trunk phase starts (from a limb stopped short, Levenberg-Marquardt
    bends the spine further than the arm falls short). `links`: `init`'s, when at hand."""
    layout = layouts[phase]
    links = host_links(body, init) if links is None else links
    beyond = beyond_bound(body, layout, init, xyz, links)
    far = out_of_reach(body, layout, init, xyz, links)
    return beyond, far, round_caps(max_steps)


# --- the drivers ------------------------------------------------------------------------
def _all_starts(body, layout, init, targets, starts: int, max_steps: int, settings: Settings):
    """Every start side by side, each one uninterrupted solve: the free vector of the first
    that reaches (else of the closest) and the steps of all."""
    problem = make_problem(body, layout, init)

    def one(k):
        x0 = jnp.zeros(layout.n_free, settings.tol_position.dtype)
        fresh = jnp.asarray(True)
        x, steps, _ = solve_free(problem, targets, x0, k, fresh, max_steps, settings)
        return x, assess(problem, init, targets, x, steps, settings)

    xs, tries = jax.vmap(one)(jnp.arange(starts))
    k = jnp.where(jnp.any(tries.ok), jnp.argmax(tries.ok), jnp.argmin(tries.cost))
    return xs[k], jnp.sum(tries.steps)


# Compiled once per problem shape and reused by every later call (under jax.grad too: their
# inputs carry no derivatives, so the compiled solve is the same).
_all_starts_jit = compiled(_all_starts)


def _answer(body, layout, init, targets, x, steps, settings: Settings) -> Attempt:
    """The attempt of a solved free vector, differentiable in everything the problem and
    the targets depend on (`assess`)."""
    return assess(make_problem(body, layout, init), init, targets, x, steps, settings, True)


_answer_jit = compiled(_answer)
_round_jit = compiled(attempt_round)


def _select(take: Array, a, b):
    """a where `take`, else b, leaf by leaf."""
    return jax.tree.map(lambda x, y: jnp.where(take, x, y), a, b)


def run_start(body, layout, init, ts, k: int, caps: list[int], tols, closed_form, planned=None):
    """Start k of a phase, in rounds of `caps` steps until the solver stops; its attempt
    counts the steps of every round. With the phase's layout and plan (`phase_plans`) the
    rounds run on their program, a limb chain's or the whole tree's (`ts` then padded,
    `padded_targets`)."""
    lay, plan = (layout, None) if planned is None else planned
    settings = Settings(*tols, closed_form if plan is None else True)  # a plan says (data)
    x = np.zeros(lay.n_free, tols[0].dtype)
    spent, fresh = 0, True
    for cap in caps:
        k_, fresh_, cap_ = np.int32(k), np.asarray(fresh), np.asarray(cap, np.int32)
        x, done, a = _round_jit(body, lay, init, ts, x, k_, fresh_, cap_, settings, plan)
        # Back on the host, as the first round's: a device array (committed to its device)
        # would compile the same round again.
        x = np.asarray(x)
        spent += int(a.steps)
        fresh = False
        if bool(done):
            break
    if plan is not None and not layout.spine:
        # The tree always names a spine target; the phase left the spine as it started.
        a = eqx.tree_at(lambda a: a.pose.spine_target, a, init.spine_target, is_leaf=is_none)
    return eqx.tree_at(lambda a: a.steps, a, np.asarray(spent))


def phase_plans(body: Body, layouts: list[Layout], phase_targets) -> list | None:
    """Each phase's layout and plan (`_tree`): a limb chain's where the phase is one
    (`make_limb_plan`), else the whole tree's; None for a phase that compiles its own
    layout: the standing phase. None in all where the solve does not fit the tree (a
    re-rooted body, a center-of-gravity target, a vertebra free without the spine).

    Why the standing phase keeps its own program: a far standing reach ends where its step
    budget runs out near a constrained equilibrium, and there rounding decides the answer
    (an accepted or rejected step flips at 1e-13), so the whole tree's arithmetic ends it
    elsewhere, no nearer to converged (docs/benchmarks.md, "Inverse kinematics"). Its
    program stays the one whose answers the reach ladder documents."""
    sets = phase_targets_of(layouts, phase_targets)
    if not fits_tree(body, sets[0]):
        return None
    tree = tree_layout(body)
    plans = []
    for k, (lay, ts) in enumerate(zip(layouts, sets)):
        if lay.standing:
            plans.append(None)
            continue
        closed, stiffness = uses_limb_start(k, ts), stiffness_of(body, lay)
        limb = make_limb_plan(body, lay, ts, closed, stiffness)
        if limb is not None:
            plans.append(limb)
            continue
        plan = make_plan(body, tree, lay, ts, closed, stiffness)
        if plan is None:
            return None
        plans.append((tree, plan))
    return plans


def uses_limb_start(phase: int, ts: TargetSet) -> bool:
    """Whether a phase's first start is the closed-form limb start: in the limbs' phase,
    unless contact is avoided. The closed form places the limb straight through whatever
    lies between, and a start inside the body stays stuck there; from `init` the solve
    slides the limb along the surfaces it meets."""
    c = ts.constraints
    return phase == 0 and (c is None or "no_contact" not in c.kinds)


def phase_targets_of(layouts: list[Layout], phase_targets: Sequence[TargetSet]) -> list[TargetSet]:
    """The target set of each layout: a single phase is the trunk's (the last)."""
    return list(phase_targets) if len(layouts) == len(phase_targets) else [phase_targets[-1]]


def solve_host(body, layouts, init, phase_targets, starts, max_steps, tols, plans=None, rest=False):
    """Phases, starts and rounds driven from the host: each runs only if needed. Returns
    the kept `Attempt`, the solver steps over all attempts, and per point target whether it
    lies beyond the reach bound of the last phase tried. `plans` (`phase_plans`): run on
    the whole tree's program (the attempts' errors then padded to the targets' buckets), or
    a limbs' phase on several limbs on each limb's chain (`_limb_groups`). `rest`: `init`
    is the standard position (its links remembered, `rest_links`)."""
    best, steps = None, 0
    start_pose = init
    for phase, (layout, ts) in enumerate(zip(layouts, phase_targets_of(layouts, phase_targets))):
        steps_k = phase_steps(layout, max_steps)
        links = rest_links(body) if rest and phase == 0 else None
        xyz = ts.point_xyz
        beyond, far, caps = phase_plan(body, layouts, phase, start_pose, xyz, steps_k, links)
        if not far.any():
            caps = round_caps(steps_k)
        planned = None if plans is None else plans[phase]
        closed = uses_limb_start(phase, ts)
        run = (body, start_pose, caps, 1 if far.any() else starts, closed, tols, plans is not None)
        groups = None
        if planned is not None and planned[1].chain is None:
            groups = limb_groups(body, layout, ts, closed)
        if groups is None:
            a, spent = _try_starts(layout, ts, planned, *run)
        else:
            tried = [_try_starts(g.layout, g.targets, g.planned, *run) for g in groups]
            a = joined(start_pose, ts, groups, [a for a, _ in tried], put=_on_device)
            a = padded_errors(a, ts)
            spent = sum(n for _, n in tried)
        steps += spent
        if best is None or bool(better(*jax.tree.map(np.asarray, (a, best)))):
            best = a
        if bool(a.ok):
            return best, steps, beyond
        start_pose = best.pose  # the trunk joins from the limbs' closest reach
    return best, steps, beyond


def _on_device(a: ArrayLike) -> Array:
    return device_array(a, np.asarray(a).dtype)


def _try_starts(layout, ts, planned, body, start_pose, caps, starts, closed, tols, pad):
    """A phase's starts in turn, until one reaches: the best attempt and the steps of all.
    `pad`: the attempts' errors padded to the whole tree's buckets, for one conclusion."""
    best, steps = None, 0
    limb = planned is not None and planned[1].chain is not None
    solved = ts if planned is None else padded_targets(ts, limb)
    for k in range(starts):
        a = run_start(body, layout, start_pose, solved, k, caps, tols, closed, planned)
        if pad and (planned is None or limb):
            a = padded_errors(a, ts)
        steps += int(a.steps)
        if best is None or bool(better(*jax.tree.map(np.asarray, (a, best)))):
            best = a
        if bool(a.ok):
            break
    return best, steps


def solve_traced(body, layouts, init, phase_targets, starts, max_steps, tols):
    """The same phases with every start side by side (for jax.grad / jit / vmap): each
    phase's solve runs without derivatives, and its answer is differentiated implicitly.
    Returns what `solve_host` does, with no target flagged as beyond. Each phase compiles
    its own layout."""
    best, steps = None, jnp.asarray(0)
    start_pose = init
    for phase, (layout, ts) in enumerate(zip(layouts, phase_targets_of(layouts, phase_targets))):
        settings = Settings(*tols, uses_limb_start(phase, ts))
        b0, p0, t0, s0 = no_gradient((body, start_pose, ts, settings))
        steps_k = phase_steps(layout, max_steps)
        x, s = _all_starts_jit(b0, layout, p0, t0, starts, steps_k, s0)
        a = _answer_jit(body, layout, start_pose, ts, x, s, settings)
        steps = steps + s
        if best is not None and (a.pose.spine_target is None) != (best.pose.spine_target is None):
            # The limbs' phase leaves the spine as in init: name it as a target, so that
            # both phases' poses have one structure to select between.
            total = spine_angles(body, body.spine, init).sum(0)
            best = eqx.tree_at(lambda b: b.pose.spine_target, best, total, is_leaf=is_none)
        best = a if best is None else _select(better(a, best), a, best)
        start_pose = best.pose
    beyond = np.zeros(phase_targets[0].point_xyz.shape[0], bool)
    return best, steps, beyond
