"""The annealed fit of one sphere cloud, from one start or several side by side
(docs/design.md, section 7); `_cloud_fit` poses it and hands back a `SphereFit`.

Expectation-maximisation with annealing: one Levenberg-Marquardt solve (`_solver`) per stage
of `STAGES` (`KNOWN_STAGES` with correspondences), each started where the previous one ended.
At a stage's start the correspondences and robust weights are fixed with the model spheres
where they are (`_cloud_residuals.pairs_at`), at the stage's temperature T and loss scale c;
its least squares is then smooth: sqrt(weight) (model - measured) per pair, plus a pull
toward the stage's start on every unknown, `STIFF` on the ones the stage holds (the first
moves only the whole body, the second the posture too, the rest the dimensions as well) and
`PULL` on the others. Spheres are (centre, radius) in m. Several starts (`fit_from_starts`)
anneal side by side and the one that explains the cloud best (`score`) is kept.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import Body, Pose
from .._solver import FitStatus, least_squares_solver, solve, tolerance
from ._cloud_residuals import (
    Cloud,
    FitLayout,
    Start,
    make_start,
    model_spheres,
    pack,
    pairs_at,
    residual_distances,
    squared_distances,
    stage_residuals,
)

INLIER_DISTANCE = 0.03  # m: a measured sphere this close to its model sphere is an inlier
# A fit lands when at least this share of the measured spheres are inliers: a landed fit of a
# cloud with 10 % outliers keeps ~90 %, one with a limb left on the wrong side ~50-80 %. A
# cloud with more outliers than 1 - LANDED_INLIERS reads as not landed.
LANDED_INLIERS = 0.75
# ... and at least this share of the model's spheres have a measured sphere within
# INLIER_DISTANCE (a limb on the wrong part of the cloud leaves its own place empty): a
# landed fit covers 0.95-0.98 at 5 mm noise and 10 % outliers, the truth itself 0.875 at
# 10 mm and 20 %; fits that did not land 0.69-0.92.
LANDED_COVERED = 0.85
SCORE_SCALE = 0.01  # m: the Geman-McClure scale of a fit's `score`
# Several starts (the searched candidates, one per heading, and the plain one) anneal side
# by side to T = 0.01 m (the first SPLIT stages), scored at MID_SCALE (m); the FINALISTS
# best run the rest. Of 32 clouds (spread 0.3, any heading, 5 mm noise, 10 % outliers) 13
# landed from the best searched start alone, 26 from the best of nine; keeping the three
# best at the split loses none of those 26 and anneals 4 starts' worth less.
SPLIT = 7
MID_SCALE = 0.02
FINALISTS = 3
STIFF = 10.0  # pull (m per unit of an unknown) that holds an unknown during a stage
PULL = 1e-4  # the weak pull toward the stage's start on the moving unknowns
# Per stage: temperature T (m), loss scale c (m), what moves (0 the whole body's placement,
# 1 the posture too, 2 the dimensions as well), whether it solves to the dtype's tolerance
# (else to 1e-4: it only hands on a start).
STAGES = (
    (0.10, 0.30, 0, False),
    (0.06, 0.20, 1, False),
    (0.04, 0.12, 1, False),
    (0.03, 0.10, 2, False),
    (0.02, 0.08, 2, False),
    (0.015, 0.06, 2, False),
    (0.01, 0.05, 2, False),
    (0.007, 0.04, 2, False),
    (0.005, INLIER_DISTANCE, 2, False),
) + ((0.003, INLIER_DISTANCE, 2, True),) * 5  # EM converges slowly: assign anew 5x
TIGHT = (1e-5, 1e-10)  # the last stages' tolerance in float32, float64
STEPS = 6  # solver steps per stage: few, each stage starts where its predecessor ended
# With correspondences there is nothing to anneal but the outlier scale, and every restart
# of Levenberg-Marquardt costs steps (its damping starts afresh): three long stages.
KNOWN_STAGES = ((0.0, 0.30, 0, False), (0.0, 0.10, 2, False), (0.0, INLIER_DISTANCE, 2, True))
# Steps per stage with correspondences: enough, with room to spare, for exact clouds posed
# and turned as a user's are to converge in a stage (docs/benchmarks.md, "Anthropometry").
KNOWN_STEPS = 80


_Arr = Array | np.ndarray  # NumPy arrays from fit_spheres_batch


def schedule(lay: FitLayout, known: bool, dtype) -> tuple[Array, ...]:
    """Per stage: T (m), c (m), the pull per unknown, the solver's tolerance."""
    T, c, moves, tight = (np.asarray(col) for col in zip(*(KNOWN_STAGES if known else STAGES)))
    pull = np.where(lay.stage_of()[None, :] <= moves[:, None], PULL, STIFF)
    tol = np.where(tight, tolerance(dtype, *TIGHT), 1e-4)
    return tuple(jnp.asarray(a, dtype) for a in (T, c, pull, tol))


def aligned(template: Body, lay: FitLayout, init: Pose, cloud: Cloud) -> Pose:
    """`init` moved by the median offset of the measured centres from the model's (of the
    matched pairs when known): robust to outliers."""
    start = make_start(template, lay, init)
    model = model_spheres(start, lay, pack(lay, start))[:, :3]
    x = cloud.measured[:, :3]
    if cloud.known:
        paired = x - model[jnp.maximum(cloud.match, 0)]
        offset = jnp.nanmedian(jnp.where((cloud.match >= 0)[:, None], paired, jnp.nan), 0)
    else:
        offset = jnp.median(x, axis=0) - jnp.median(model, axis=0)
    offset = jnp.where(jnp.isfinite(offset), offset, 0.0)
    return dataclasses.replace(init, position=init.position + offset)


def score(distances: Float[Array, " m"], scale: float = SCORE_SCALE) -> Array:
    """How well a fit explains its cloud: the mean Geman-McClure cost d^2 / (d^2 + scale^2)
    of each measured sphere's residual distance d (m), in [0, 1), 0 a perfect fit. With 5 mm
    of noise on every number a landed fit scores about 0.48 (10 % outliers: 0.5), one with a
    limb on the wrong part of the cloud 0.55-0.85."""
    d2 = distances**2
    return jnp.mean(d2 / (d2 + scale**2))


def begin(template: Body, lay: FitLayout, init: Pose, cloud: Cloud, align: Array):
    """A fit's start from `init` (moved by the cloud's median offset when `align`): (the
    pose it starts from, its `Start`, the annealing's carry: unknowns, no failure, steps,
    whether the last stage stood still)."""
    init = jax.tree.map(
        lambda a, b: jnp.where(align, a, b), aligned(template, lay, init, cloud), init
    )
    start = make_start(template, lay, init)
    z = pack(lay, start)
    return init, start, (z, jnp.asarray(True), jnp.asarray(0), jnp.asarray(False))


def anneal(start: Start, lay: FitLayout, cloud: Cloud, carry, stages):
    """The annealing's `stages` (rows of `schedule`) from `carry` (`begin`): one solve per
    stage, its pairs fixed at the stage's start (module docstring)."""

    def stage(carry, xs):
        z, ok, steps, _ = carry
        T, c, pull, tol = xs
        pairs = pairs_at(cloud, model_spheres(start, lay, z), T, c)
        out = solve(
            stage_residuals,
            least_squares_solver(tol),
            z,
            (start, lay, pairs, z, pull),
            KNOWN_STEPS if cloud.known else STEPS,
        )
        # Converged: the solve met its tolerance, or the stage (a whole EM round at the
        # end) moved no unknown by more than 100x the tolerance (float32 rarely meets
        # Levenberg-Marquardt's own test in a few steps once the answer is found).
        still = jnp.max(jnp.abs(out.value - z)) <= 100 * tol
        done = (out.status == FitStatus.CONVERGED) | still
        ok = ok & (out.status != FitStatus.FAILED)
        return (out.value, ok, steps + out.steps, done), None

    return jax.lax.scan(stage, carry, stages)[0]


def distances_at(start: Start, lay: FitLayout, cloud: Cloud, z: Array) -> tuple[Array, Array]:
    """Each measured sphere's residual distance (m,) m at the unknowns z, and the share of
    the model's spheres within `INLIER_DISTANCE` of a measured one."""
    d2 = squared_distances(cloud.measured, model_spheres(start, lay, z))
    covered = jnp.mean(jnp.min(d2, axis=0) < INLIER_DISTANCE**2, dtype=d2.dtype)
    return residual_distances(cloud, d2), covered


def conclude(init: Pose, start: Start, lay: FitLayout, cloud: Cloud, carry, z_start: Array):
    """A `Fitted` from the annealing's last carry (a failed solve falls back to the start)."""
    z, ok, steps, done = carry
    z = jnp.where(ok, z, z_start)
    x, log_axial, log_radial = lay.split(z, start)
    distances, covered = distances_at(start, lay, cloud, z)
    settled = done & landed_by(distances, covered)
    status = jnp.where(
        ok, jnp.where(settled, FitStatus.CONVERGED, FitStatus.NOT_CONVERGED), FitStatus.FAILED
    )
    best = score(distances)
    return Fitted(
        start.problem.pose(x, init),
        log_axial,
        log_radial,
        distances,
        covered,
        status,
        steps,
        best,
        jnp.full_like(best, jnp.inf),
    )


def landed_by(distances: _Arr, covered: _Arr) -> _Arr:
    """Whether a fit landed: at least `LANDED_INLIERS` of the measured spheres are inliers
    and at least `LANDED_COVERED` of the model's spheres have a measured sphere near them."""
    inliers = jnp.mean(distances < INLIER_DISTANCE, axis=-1)
    return (inliers >= LANDED_INLIERS) & (covered >= LANDED_COVERED)


class Fitted(eqx.Module):
    """What a compiled fit hands back, per cloud (`SphereFit` before the body is scaled)."""

    pose: Pose
    log_axial: Array
    log_radial: Array
    distances: Array
    covered: Array
    status: Array
    steps: Array
    score: Array
    runner_up: Array


def fit_cloud(template: Body, lay: FitLayout, init: Pose, cloud: Cloud, align: Array) -> Fitted:
    """The annealed fit of one cloud (module docstring) from `init`. `align`: first move
    the start by the cloud's median offset."""
    init, start, carry = begin(template, lay, init, cloud, align)
    stages = schedule(lay, cloud.known, carry[0].dtype)
    return conclude(init, start, lay, cloud, anneal(start, lay, cloud, carry, stages), carry[0])


def fit_from_starts(template: Body, lay: FitLayout, inits: Pose, align, cloud: Cloud) -> Fitted:
    """The annealed fit from several starts side by side (a leading axis on `inits` and
    `align`): every start runs the first `SPLIT` stages, the `FINALISTS` that then explain
    the cloud best (`score` at `MID_SCALE`: the fit is not yet cold) run the rest, and the
    one of least `score` is kept, the next one's score its `runner_up`. The steps are those
    of every start."""
    inits, starts, begun = jax.vmap(lambda i, a: begin(template, lay, i, cloud, a))(inits, align)
    z_starts = begun[0]
    stages = schedule(lay, False, z_starts.dtype)
    early = jax.tree.map(lambda a: a[:SPLIT], stages)
    late = jax.tree.map(lambda a: a[SPLIT:], stages)
    carries = jax.vmap(lambda st, c: anneal(st, lay, cloud, c, early))(starts, begun)
    z_mid, steps_mid = carries[0], carries[2]
    mid = jax.vmap(lambda st, z: score(distances_at(st, lay, cloud, z)[0], MID_SCALE))(
        starts, z_mid
    )
    top = jnp.argsort(mid)[:FINALISTS]
    early_steps = jnp.sum(steps_mid) - jnp.sum(steps_mid[top])
    init, start, z_start, carries = jax.tree.map(
        lambda a: a[top], (inits, starts, z_starts, carries)
    )

    def finish(init, start, carry, z_start):
        carry = anneal(start, lay, cloud, carry, late)
        return conclude(init, start, lay, cloud, carry, z_start)

    fits = jax.vmap(finish)(init, start, carries, z_start)
    order = jnp.argsort(fits.score)
    best = jax.tree.map(lambda a: a[order[0]], fits)
    steps = early_steps + jnp.sum(fits.steps)
    return dataclasses.replace(best, runner_up=fits.score[order[1]], steps=steps)
