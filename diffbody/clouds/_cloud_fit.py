"""Fitting a posture and a body's dimensions to a measured sphere cloud (`fit_spheres`,
`fit_spheres_batch`; docs/design.md, section 7).

Expectation-maximisation with annealing, from the starts that `_cloud_start` searches for
when the correspondences are unknown (side by side, the one that explains the cloud best
kept: `fit_from_starts`): one Levenberg-Marquardt solve (`_solver`) per stage
of `STAGES` (`KNOWN_STAGES` with correspondences), each started where the previous one ended.
At a stage's start the correspondences and robust weights are fixed with the model spheres
where they are (`_cloud_residuals.pairs_at`), at the stage's temperature T and loss scale c;
its least squares is then smooth: sqrt(weight) (model - measured) per pair, plus a pull
toward the stage's start on every unknown, `STIFF` on the ones the stage holds (the first
moves only the whole body, the second the posture too, the rest the dimensions as well) and
`PULL` on the others. Spheres are (centre, radius) in m.
"""

import dataclasses
import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._body import Body, Pose, without_names
from .._programs import compiled
from .._solver import FitStatus, least_squares_solver, solve, tolerance
from .._spine import spine_angles
from ..anthropometry._scaling import log_scaled
from ..runs._batches import chunk_rows, map_chunks
from ..runs._chunk_store import ChunkStore, float_name, input_hash
from ..runs._header import body_fields
from ..runs._streaming import tree_hash
from ._cloud_residuals import (
    FIT_NAMES,
    Cloud,
    FitLayout,
    Start,
    fit_layout,
    make_start,
    model_spheres,
    pack,
    pairs_at,
    residual_distances,
    squared_distances,
    stage_residuals,
)
from ._cloud_start import search_start, search_tables
from ._clouds import check_correspondences, check_spheres

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


class SphereFit(eqx.Module):
    """What `fit_spheres` returns; `fit_spheres_batch` the same with a leading batch axis on
    every array, the body's included (`SphereFit.item(i)` takes one out)."""

    body: Body  # the body scaled by the fitted factors
    pose: Pose
    axial: Float[_Arr, "*b n_group"]  # axial scale factors, `SCALE_GROUPS` order
    radial: Float[_Arr, "*b n_group"]  # radial scale factors
    residuals: Float[_Arr, "*b m"]  # m: (centre, radius) distance of each measured sphere
    # to its matched model sphere (to the nearest one without correspondences)
    inliers: Bool[_Arr, "*b m"]  # residual below INLIER_DISTANCE
    covered: Float[_Arr, "*b"]  # share of the model's spheres within INLIER_DISTANCE of a
    # measured sphere
    landed: Bool[_Arr, "*b"]  # at least LANDED_INLIERS of the spheres are inliers and
    # LANDED_COVERED of the model's spheres covered
    score: Float[_Arr, "*b"]  # the kept fit's `score` (0 perfect; lower explains more)
    runner_up: Float[_Arr, "*b"]  # the next start's score; inf when one start was fitted
    # (an `init` or correspondences given)
    status: Int[_Arr, "*b"]  # a FitStatus: CONVERGED only when landed (a fit that settled
    # with a limb on the wrong part of the cloud is NOT_CONVERGED, `landed` False)
    steps: Int[_Arr, "*b"]  # solver steps over all stages

    @property
    def converged(self) -> Bool[Array, "*b"]:
        return self.status == FitStatus.CONVERGED

    def item(self, i: int) -> "SphereFit":
        """Cloud i of a batch, as JAX arrays (ready for `forward`, `render`, ...)."""
        return jax.tree.map(lambda a: jnp.asarray(a[i]) if eqx.is_array(a) else a, self)


# --- the fit -------------------------------------------------------------------------------
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


def searched(template: Body, lay: FitLayout, init: Pose, cloud: Cloud, tables) -> Pose:
    """The `_cloud_start.search_start` candidates for `init` (the standard position) on the
    cloud, one per heading, best first: a pose with a leading axis of `YAWS`."""
    rest = make_start(template, lay, init)
    xs, _ = search_start(rest, lay, cloud, tables)
    return jax.vmap(lambda x: rest.problem.pose(x, init))(xs)


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
    begun = jax.vmap(lambda i, a: begin(template, lay, i, cloud, a))(inits, align)
    stages = schedule(lay, False, begun[2][0].dtype)
    early = jax.tree.map(lambda a: a[:SPLIT], stages)
    late = jax.tree.map(lambda a: a[SPLIT:], stages)
    carries = jax.vmap(lambda st, c: anneal(st, lay, cloud, c, early))(begun[1], begun[2])
    mid = jax.vmap(lambda st, z: score(distances_at(st, lay, cloud, z)[0], MID_SCALE))(
        begun[1], carries[0]
    )
    top = jnp.argsort(mid)[:FINALISTS]
    init, start, z_start = jax.tree.map(lambda a: a[top], (begun[0], begun[1], begun[2][0]))
    early_steps = jnp.sum(carries[2]) - jnp.sum(carries[2][top])
    carries = jax.tree.map(lambda a: a[top], carries)

    def finish(init, start, carry, z_start):
        carry = anneal(start, lay, cloud, carry, late)
        return conclude(init, start, lay, cloud, carry, z_start)

    fits = jax.vmap(finish)(init, start, carries, z_start)
    order = jnp.argsort(fits.score)
    best = jax.tree.map(lambda a: a[order[0]], fits)
    steps = early_steps + jnp.sum(fits.steps)
    return dataclasses.replace(best, runner_up=fits.score[order[1]], steps=steps)


def fit_one(template, lay, init, cloud, align, tables) -> Fitted:
    """`fit_cloud`; when `tables` (static) is not None, from the searched starts and `init`
    moved onto the cloud (`fit_from_starts`)."""
    if tables is None:
        return fit_cloud(template, lay, init, cloud, jnp.asarray(align))
    return _from_starts(template, lay, searched(template, lay, init, cloud, tables), init, cloud)


def _from_starts(template, lay, found: Pose, init: Pose, cloud: Cloud) -> Fitted:
    """`fit_from_starts` of the searched candidates and `init` moved onto the cloud (the
    search's chamfer cost can prefer a start that anneals worse than the plain one on a
    cloud near the standard position: docs/benchmarks.md, "Anthropometry")."""
    if init.spine_target is None:
        # One structure for all: the searched starts name the spine as their target.
        total = spine_angles(template, template.spine, init).sum(0)
        init = dataclasses.replace(init, spine_target=total)
    inits = jax.tree.map(lambda a, b: jnp.concatenate([a, b[None]]), found, init)
    align = jnp.arange(inits.position.shape[0]) == inits.position.shape[0] - 1
    return fit_from_starts(template, lay, inits, align, cloud)


def fit_many(template, lay, init, clouds, align, tables) -> Fitted:
    """`fit_one` of a chunk of clouds: the searches one after the other (`lax.map`: a vmap
    of the search's vmapped candidates trips XLA's dot simplifier, and one search already
    fills the cores), the fits vmapped (each from its starts, as `fit_one`)."""
    if tables is None:
        fit = eqx.filter_vmap(fit_cloud, in_axes=(None, None, None, 0, None))
        return fit(template, lay, init, clouds, jnp.asarray(align))
    found = jax.lax.map(lambda c: searched(template, lay, init, c, tables), clouds)
    return jax.vmap(lambda f, c: _from_starts(template, lay, f, init, c))(found, clouds)


# One compiled fit per (body structure, layout, cloud size, start); the batch one per chunk.
_fit_jit = compiled(fit_one)
_fit_many_jit = compiled(fit_many)


# --- the public functions ------------------------------------------------------------------
def _fit_names(fit) -> tuple[str, ...]:
    fit = (fit,) if isinstance(fit, str) else tuple(fit)
    unknown = [f for f in fit if f not in FIT_NAMES]
    if unknown or not fit:
        raise ValueError(
            f"fit: {unknown or 'nothing'} is not a choice of unknowns; give a non-empty subset "
            f"of {FIT_NAMES}"
        )
    return fit


def _prepare(body: Body, centers, radii, correspondences, fit, init: Pose | None, batch: bool):
    """The host's part of a fit, every argument checked: (template, layout, start pose,
    measured spheres (..., m, 4), correspondences or None, the start search's tables or
    None: searched without correspondences from no `init` when the pose moves)."""
    fit = _fit_names(fit)
    layout = fit_layout(body, fit)
    measured = check_spheres(centers, radii, batch=batch)
    match = check_correspondences(correspondences, measured.shape[:-1], len(body.sphere_radii))
    start = body.rest_pose() if init is None else init
    search = init is None and match is None and "pose" in fit
    tables = search_tables(body, layout) if search else None
    return without_names(body), layout, start, measured, match, tables


def _cloud(dtype, measured: np.ndarray, match: np.ndarray | None) -> Cloud:
    none = np.full(measured.shape[:-1], -1, np.int32)
    return Cloud(
        measured=jnp.asarray(measured, dtype),
        match=jnp.asarray(none if match is None else match),
        known=match is not None,
    )


def _result(body: Body, template: Body, out: Fitted) -> SphereFit:
    fitted = jax.vmap(log_scaled, in_axes=(None, 0, 0)) if out.log_axial.ndim == 2 else log_scaled
    # Named before scaling: a batch of bodies is no valid argument of Body's constructor.
    name = dict(name=f"{body.name}-fitted", source="diffbody.fit_spheres")
    template = dataclasses.replace(template, **name)
    return SphereFit(
        body=fitted(template, out.log_axial, out.log_radial),
        pose=out.pose,
        axial=jnp.exp(out.log_axial),
        radial=jnp.exp(out.log_radial),
        residuals=out.distances,
        inliers=out.distances < INLIER_DISTANCE,
        covered=out.covered,
        landed=landed_by(out.distances, out.covered),
        score=out.score,
        runner_up=out.runner_up,
        status=out.status,
        steps=out.steps,
    )


def fit_spheres(
    body: Body,
    centers: ArrayLike,
    radii: ArrayLike,
    *,
    correspondences: ArrayLike | None = None,
    fit: tuple[str, ...] = FIT_NAMES,
    init: Pose | None = None,
) -> SphereFit:
    """Fit a posture and the body's dimensions to a measured sphere cloud (docs/design.md,
    section 7).

    centers (m, 3) and radii (m,), in m (checked on the host, so that a wrong shape gets
    a message, not a type error): the measured spheres, any number, outliers allowed.
    correspondences: (m,) the model sphere (index into `body`'s spheres) each measured sphere
    is, -1 for none (an outlier); None when unknown (annealed soft assignment, module
    docstring). fit: which unknowns move, a subset of ("pose", "lengths", "radii"):
    "lengths" are the axial and "radii" the radial scale factors of `SCALE_GROUPS` (left
    and right share one); the rest stays as in `init` and at unit scale. init None: the
    standard position, searched for over the whole body's heading and the limbs' postures
    without correspondences (`_cloud_start`), moved onto the cloud by its median offset
    with them.

    Returns a `SphereFit`: the scaled body, the pose (its spine as a Bendspine target),
    the scale factors, each measured sphere's residual distance and inlier flag, whether
    the fit landed (`LANDED_INLIERS`) and a status (CONVERGED only when landed).
    """
    template, lay, start, measured, match, tables = _prepare(
        body, centers, radii, correspondences, fit, init, batch=False
    )
    cloud = _cloud(template.lengths.dtype, measured, match)
    out = _fit_jit(template, lay, start, cloud, init is None, tables)
    return _result(body, template, out)


def fit_spheres_batch(
    body: Body,
    centers: ArrayLike,
    radii: ArrayLike,
    *,
    correspondences: ArrayLike | None = None,
    fit: tuple[str, ...] = FIT_NAMES,
    init: Pose | None = None,
    chunk_size: int = 256,
    progress: bool = True,
    out: str | os.PathLike | None = None,
    resume: bool = False,
) -> SphereFit:
    """`fit_spheres` of many clouds of one size at once: one compiled, vmapped fit per chunk
    of `chunk_size` clouds (the last chunk padded), with a progress bar on stderr.

    centers (b, m, 3), radii (b, m); correspondences (m,) shared or (b, m), or None; `init`
    one pose for every cloud. Returns a `SphereFit` with a leading batch axis (NumPy
    arrays); a cloud whose fit fails has status FAILED and does not stop the others.

    `out`: a folder that keeps every finished chunk as it is done; an interrupt raises
    `Interrupted` (a KeyboardInterrupt) saying how many clouds it holds, and `resume=True`
    reads those and fits the rest (refused, naming what changed, for other clouds or
    settings).
    """
    if not (isinstance(chunk_size, int) and chunk_size >= 1):
        raise ValueError(f"chunk_size: expected an integer >= 1, got {chunk_size!r}")
    template, lay, start, measured, match, tables = _prepare(
        body, centers, radii, correspondences, fit, init, batch=True
    )
    dtype = template.lengths.dtype
    none = np.full(measured.shape[:-1], -1, np.int32)
    known = match is not None

    def run(measured, match):
        cloud = Cloud(measured=measured.astype(dtype), match=match, known=known)
        return _fit_many_jit(template, lay, start, cloud, init is None, tables)

    chunk = chunk_rows(chunk_size, measured.shape[0])
    store = None
    if out is not None:
        given = input_hash(centers, radii, correspondences)
        settings = {"function": "fit_spheres_batch", "clouds": given, "fit": " ".join(fit)}
        settings |= dict(body_fields(body)) | {
            "init": "(none)" if init is None else tree_hash(init)
        }
        store = ChunkStore.open(out, settings | {"float": float_name()}, chunk, resume)
    fitted = map_chunks(
        run,
        (measured, none if match is None else match),
        chunk=chunk,
        progress=progress,
        label="fit",
        unit="cloud",
        store=store,
    )
    result = _result(body, template, fitted)
    return jax.tree.map(lambda a: np.asarray(a) if eqx.is_array(a) else a, result)
