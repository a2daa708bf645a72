"""Fitting a posture and a body's dimensions to a measured sphere cloud (docs/design.md, section 7).

Unknowns: the pose as the reach core's free vector (`_unknowns`, the whole tree, the root
placement free, the spine as its Bendspine target, every limit exact through the bounded
maps) and the logarithms of the axial ("lengths") and radial ("radii") scale factors of
the scale groups (`_scaling.SCALE_GROUPS`, left and right share one), applied with
`scale_body`. `fit` chooses which move; the others stay as in `init`.

The fit is expectation-maximisation with annealing, one optimistix Levenberg-Marquardt
solve per stage of `STAGES`, each started where the previous one ended. At the start of a
stage, with the model spheres where they are:

- Correspondences. Known: each measured sphere is its matched model sphere. Unknown: a soft
  assignment, each measured sphere to its `CANDIDATES` nearest model spheres in (centre,
  radius) space with weights softmax(-d^2 / 2 T^2), and each model sphere to its nearest
  measured spheres the same way (without that term a body that covers the cloud with part
  of itself would fit as well). The temperature T anneals from 10 cm to 2 mm: at first a
  sphere is pulled toward the blurred middle of its neighbours, at the end toward its
  nearest one.
- Robust weights. Each pair's Geman-McClure weight 1 / (1 + d^2 / c^2)^2 (iteratively
  reweighted least squares for the loss d^2 / (1 + d^2 / c^2), which is bounded by c^2 so
  that an outlier's pull vanishes as 1 / d^3). c anneals with T (graduated
  non-convexity, Yang et al. 2020) down to `LOSS_SCALE`, about the length of the
  (centre, radius) error of 5 mm noise per number.

The stage's least squares is then smooth: residual rows sqrt(weight) (model - measured) for
the weighted pairs, plus a pull toward the stage's start on every unknown, `STIFF` on the
ones a stage holds (the first moves only the whole body, the second the posture too, the
rest the dimensions as well) and `PULL` on the others, which settles directions the spheres
do not see (a straight limb's twist) and is ~1e-9 relative at the answer.
"""

import dataclasses
import enum
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._body import Body, Pose, without_names
from .._kinematics import place_on_segments
from .._progress import Progress
from ..anthropometry._scaling import N_GROUPS, per_segment, scale_body
from ..ik._problem import Problem, global_order, make_problem
from ..ik._unknowns import Layout, whole_tree_layout
from ._clouds import check_correspondences, check_spheres

FIT_NAMES = ("pose", "lengths", "radii")
SINKHORN = 30  # rounds of normalisation of one soft assignment
C_MEDIAN = 3.0  # the outlier scale is at least this many median residual distances
INLIER_DISTANCE = 0.03  # m: a measured sphere this close to its model sphere is an inlier
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
STEPS = 6  # solver steps per stage: few, each stage starts where its predecessor ended
# With correspondences there is nothing to anneal but the outlier scale, and every restart
# of Levenberg-Marquardt costs steps (its damping starts afresh): three long stages.
KNOWN_STAGES = ((0.0, 0.30, 0, False), (0.0, 0.10, 2, False), (0.0, INLIER_DISTANCE, 2, True))
KNOWN_STEPS = 40


# The damped normal equations by Cholesky (the pulls and the damping keep them well posed):
# the stage problems are ~100 unknowns against ~3,000 rows.
LINEAR_SOLVER = lx.Normal(lx.Cholesky())


_Arr = Array | np.ndarray  # NumPy arrays from fit_spheres_batch


class FitStatus(enum.IntEnum):
    """What a fit reports (`SphereFit.status`)."""

    CONVERGED = 0  # the last stage met its tolerance, or moved nothing by 100x more
    NOT_CONVERGED = 1  # the last stage ran out of steps: its last point is returned
    FAILED = 2  # a value became non-finite: the start is returned


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
    status: Int[_Arr, "*b"]  # a FitStatus
    steps: Int[_Arr, "*b"]  # solver steps over all stages

    @property
    def converged(self) -> Bool[Array, "*b"]:
        return self.status == FitStatus.CONVERGED

    def item(self, i: int) -> "SphereFit":
        """Cloud i of a batch, as JAX arrays (ready for `forward`, `render`, ...)."""
        return jax.tree.map(lambda a: jnp.asarray(a[i]) if eqx.is_array(a) else a, self)


# --- unknowns ------------------------------------------------------------------------------
@dataclass(frozen=True)
class FitLayout:
    """What moves (static): the reach layout of the whole tree for the pose, and which of
    the parts [pose free vector | log axial (n_group) | log radial (n_group)] are unknowns."""

    pose: Layout
    fit: tuple[str, ...]

    @property
    def sizes(self) -> tuple[int, int, int]:
        return tuple(
            n if name in self.fit else 0
            for name, n in zip(FIT_NAMES, (self.pose.n_free, N_GROUPS, N_GROUPS))
        )

    def split(self, z: Array, start: "Start") -> tuple[Array, Array, Array]:
        """The pose free vector and the two log scales, the held ones from the start."""
        parts = jnp.split(z, np.cumsum(self.sizes)[:-1])
        held = (start.x, start.log_axial, start.log_radial)
        return tuple(p if n else h for p, n, h in zip(parts, self.sizes, held))

    def stage_of(self) -> np.ndarray:
        """Per unknown, the first stage kind that moves it (0 root, 1 posture, 2 scales)."""
        n_root = 6
        pose = np.r_[np.ones(self.pose.n_free - n_root, int), np.zeros(n_root, int)]
        parts = (pose, np.full(N_GROUPS, 2), np.full(N_GROUPS, 2))
        return np.concatenate([p for p, n in zip(parts, self.sizes) if n])


def fit_layout(body: Body, fit: tuple[str, ...]) -> FitLayout:
    """The whole tree free within its limits, the spine as its target, the root free."""
    return FitLayout(pose=whole_tree_layout(body), fit=tuple(n for n in FIT_NAMES if n in fit))


class Start(eqx.Module):
    """The start of a fit: the reach problem of `init` (whose free vector x is the pose's
    start) and the start's log scale factors (zero: the template's own dimensions)."""

    problem: Problem
    x: Float[Array, " n_free"]
    log_axial: Float[Array, " n_group"]
    log_radial: Float[Array, " n_group"]


def make_start(template: Body, lay: FitLayout, init: Pose) -> Start:
    problem = make_problem(template, lay.pose, init)
    zeros = jnp.zeros(N_GROUPS, problem.x0.dtype)
    return Start(problem, problem.x0, zeros, zeros)


def scaled(template: Body, log_axial: Array, log_radial: Array) -> Body:
    """The template with the group scale factors exp(log_axial), exp(log_radial)."""
    axial = per_segment(template, jnp.exp(log_axial))
    radial = per_segment(template, jnp.exp(log_radial))
    return scale_body(template, axial, radial)


def model_spheres(start: Start, lay: FitLayout, z: Array) -> Float[Array, "n_sph 4"]:
    """World centres and radii (m) of the model's spheres for the unknowns z: one walk."""
    x, log_axial, log_radial = lay.split(z, start)
    body = scaled(start.problem.body, log_axial, log_radial)
    problem = dataclasses.replace(start.problem, body=body)
    links, tau = problem.links(x)
    links = global_order(lay.pose, links)
    tau = tau[np.argsort(np.asarray(lay.pose.chain.segments))]
    seg = np.asarray(body.sphere_segment, dtype=int)
    origins = body.sphere_origins
    local = place_on_segments(body, seg, origins, origins[:, 2], links.R_base[seg], tau[seg])
    centers = links.p_proximal[seg] + local
    return jnp.concatenate([centers, body.sphere_radii[:, None]], axis=-1)


# --- one stage -----------------------------------------------------------------------------
class Cloud(eqx.Module):
    """One measured cloud: one compiled fit serves every cloud of a size."""

    measured: Float[Array, "*b m 4"]  # centre and radius (m) of each measured sphere
    match: Int[Array, "*b m"]  # its model sphere, -1 for none (unused when not `known`)
    known: bool = eqx.field(static=True)  # whether `match` holds (else soft assignment)


class Pairs(eqx.Module):
    """One stage's fixed assignment: per model sphere, the weighted mean of the measured
    spheres matched to it (n_sph, 4) and the weight of that match (n_sph,), 0 for none."""

    toward: Float[Array, "n_sph 4"]
    weight: Float[Array, " n_sph"]


def squared_distances(measured: Array, model: Array) -> Float[Array, "m n"]:
    """(m, n) m^2: between every measured and every model sphere in (centre, radius) space."""
    return jnp.sum((measured[:, None, :] - model[None]) ** 2, axis=-1)


def softassign(d2: Float[Array, "m n"], T: Array, c: Array) -> Float[Array, "m n"]:
    """The soft one-to-one assignment of measured to model spheres (Gold & Rangarajan's
    softassign): exp(-d^2 / 2 T^2) made doubly stochastic by `SINKHORN` rounds of row and
    column normalisation in the log domain, with a slack row and column of value
    exp(-c^2 / 2 T^2), so that a sphere farther than c from every partner (an outlier, or a
    model sphere nothing was measured of) goes to the slack. One-to-one, unlike the
    nearest sphere, it cannot slide a chain of spheres along itself (a foot fitted too
    long, every toe sphere on its neighbour's place). d2: `squared_distances`."""
    m, n = d2.shape
    slack = -(c**2) / (2 * T**2)
    L = jnp.pad(-d2 / (2 * T**2), ((0, 1), (0, 1)), constant_values=slack)
    L = L.at[m, n].set(-jnp.inf)  # the slacks do not match each other

    def normalise(_, L):
        L = L.at[:m].add(-jax.nn.logsumexp(L[:m], axis=1, keepdims=True))
        return L.at[:, :n].add(-jax.nn.logsumexp(L[:, :n], axis=0, keepdims=True))

    return jnp.exp(jax.lax.fori_loop(0, SINKHORN, normalise, L)[:m, :n])


def _robust(d2: Array, c: Array) -> Array:
    """The Geman-McClure IRLS weight of a pair at squared distance d2."""
    return 1.0 / (1.0 + d2 / c**2) ** 2


def pairs_at(cloud: Cloud, model: Array, T: Array, c: Array) -> Pairs:
    """The stage's pairs with the model spheres at `model` (module docstring). The outlier
    scale is c or three times the median distance of the measured spheres to their
    partners (matched, or nearest), whichever is larger, so that a far start (a limb 50 cm
    from its place) is not taken for outliers: as the fit closes in, c rules."""
    d2_all = squared_distances(cloud.measured, model)
    median = jnp.median(residual_distances(cloud, d2_all))
    c = jnp.maximum(c, C_MEDIAN * median)
    # No colder than the noise: the median (centre, radius) distance of a 4-vector of
    # Gaussian noise of deviation s per number is 1.83 s.
    T = jnp.maximum(T, median / 1.83)
    if cloud.known:
        matched = jnp.maximum(cloud.match, 0)
        d2 = jnp.take_along_axis(d2_all, matched[:, None], axis=1)[:, 0]
        P = jax.nn.one_hot(matched, model.shape[0], dtype=model.dtype)
        P = P * jnp.where(cloud.match >= 0, _robust(d2, c), 0.0)[:, None]
    else:
        P = softassign(d2_all, T, c)
    weight = jnp.sum(P, axis=0)
    toward = (P.T @ cloud.measured) / jnp.maximum(weight, 1e-30)[:, None]
    return Pairs(toward, weight)


def stage_residuals(z: Array, args) -> Array:
    """One stage's residual vector: sqrt(weight) (model sphere - its matched mean) (4 per
    model sphere), then the pulls (one per unknown)."""
    start, lay, pairs, z0, pull = args
    model = model_spheres(start, lay, z)
    e = jnp.sqrt(pairs.weight)[:, None] * (model - pairs.toward)
    return jnp.concatenate([e.ravel(), pull * (z - z0)])


def residual_distances(cloud: Cloud, d2: Float[Array, "m n"]) -> Float[Array, " m"]:
    """(m,) m: each measured sphere's (centre, radius) distance to its matched model sphere,
    to the nearest one where none is known. d2: `squared_distances`."""
    nearest = jnp.min(d2, axis=-1)
    if cloud.known:
        matched = jnp.take_along_axis(d2, jnp.maximum(cloud.match, 0)[:, None], axis=1)[:, 0]
        nearest = jnp.where(cloud.match >= 0, matched, nearest)
    return jnp.sqrt(nearest)


# --- the fit -------------------------------------------------------------------------------
def schedule(lay: FitLayout, known: bool, dtype) -> tuple[Array, ...]:
    """Per stage: T (m), c (m), the pull per unknown, the solver's tolerance."""
    T, c, moves, tight = (np.asarray(col) for col in zip(*(KNOWN_STAGES if known else STAGES)))
    pull = np.where(lay.stage_of()[None, :] <= moves[:, None], PULL, STIFF)
    tol = np.where(tight, 1e-10 if dtype == jnp.float64 else 1e-5, 1e-4)
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


def pack(lay: FitLayout, start: Start) -> Array:
    parts = (start.x, start.log_axial, start.log_radial)
    return jnp.concatenate([p for p, n in zip(parts, lay.sizes) if n])


def fit_cloud(template: Body, lay: FitLayout, init: Pose, cloud: Cloud, align: Array):
    """The annealed fit of one cloud (module docstring): (the pose free vector and log
    scales, the residual distances (m,), status, steps). `align`: first move the start by
    the cloud's median offset."""
    init = jax.tree.map(
        lambda a, b: jnp.where(align, a, b), aligned(template, lay, init, cloud), init
    )
    start = make_start(template, lay, init)
    z_start = pack(lay, start)

    def stage(carry, xs):
        z, ok, steps, _ = carry
        T, c, pull, tol = xs
        pairs = pairs_at(cloud, model_spheres(start, lay, z), T, c)
        solver = optx.LevenbergMarquardt(rtol=tol, atol=tol, linear_solver=LINEAR_SOLVER)
        sol = optx.least_squares(
            stage_residuals,
            solver,
            z,
            (start, lay, pairs, z, pull),
            max_steps=KNOWN_STEPS if cloud.known else STEPS,
            throw=False,
        )
        finite = jnp.all(jnp.isfinite(sol.value))
        # Converged: the solve met its tolerance, or the stage (a whole EM round at the
        # end) moved no unknown by more than 100x the tolerance (float32 rarely meets
        # Levenberg-Marquardt's own test in a few steps once the answer is found).
        still = jnp.max(jnp.abs(sol.value - z)) <= 100 * tol
        done = (sol.result == optx.RESULTS.successful) | still
        z = jnp.where(finite, sol.value, z)
        return (z, ok & finite, steps + sol.stats["num_steps"], done), None

    carry = (z_start, jnp.asarray(True), jnp.asarray(0), jnp.asarray(False))
    (z, ok, steps, done), _ = jax.lax.scan(stage, carry, schedule(lay, cloud.known, z_start.dtype))
    z = jnp.where(ok, z, z_start)
    status = jnp.where(
        ok, jnp.where(done, FitStatus.CONVERGED, FitStatus.NOT_CONVERGED), FitStatus.FAILED
    )
    x, log_axial, log_radial = lay.split(z, start)
    model = model_spheres(start, lay, z)
    distances = residual_distances(cloud, squared_distances(cloud.measured, model))
    pose = start.problem.pose(x, init)
    return pose, log_axial, log_radial, distances, status, steps


# One compiled fit per (body structure, layout, cloud size); the batch one per chunk size.
_fit_jit = eqx.filter_jit(fit_cloud)
_fit_many_jit = eqx.filter_jit(eqx.filter_vmap(fit_cloud, in_axes=(None, None, None, 0, None)))


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
    measured spheres (..., m, 4), correspondences or None)."""
    layout = fit_layout(body, _fit_names(fit))
    measured = check_spheres(centers, radii, batch=batch)
    match = check_correspondences(correspondences, measured.shape[:-1], len(body.sphere_radii))
    start = body.rest_pose() if init is None else init
    return without_names(body), layout, start, measured, match


def _cloud(dtype, measured: np.ndarray, match: np.ndarray | None) -> Cloud:
    none = np.full(measured.shape[:-1], -1, np.int32)
    return Cloud(
        measured=jnp.asarray(measured, dtype),
        match=jnp.asarray(none if match is None else match),
        known=match is not None,
    )


def _result(body: Body, template: Body, out) -> SphereFit:
    pose, log_axial, log_radial, distances, status, steps = out
    fitted = jax.vmap(scaled, in_axes=(None, 0, 0)) if log_axial.ndim == 2 else scaled
    # Named before scaling: a batch of bodies is no valid argument of Body's constructor.
    name = dict(name=f"{body.name}-fitted", source="diffbody.fit_spheres")
    template = dataclasses.replace(template, **name)
    return SphereFit(
        body=fitted(template, log_axial, log_radial),
        pose=pose,
        axial=jnp.exp(log_axial),
        radial=jnp.exp(log_radial),
        residuals=distances,
        inliers=distances < INLIER_DISTANCE,
        status=status,
        steps=steps,
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
    and right share one); the rest stays as in `init` (the standard position when None,
    moved onto the cloud by its median offset) and at unit scale. The whole body faces
    +X in the standard position: give an `init` facing the cloud's way when it faces
    another.

    Returns a `SphereFit`: the scaled body, the pose (its spine as a Bendspine target),
    the scale factors, each measured sphere's residual distance and inlier flag, a status.
    """
    template, lay, start, measured, match = _prepare(
        body, centers, radii, correspondences, fit, init, batch=False
    )
    cloud = _cloud(template.lengths.dtype, measured, match)
    out = _fit_jit(template, lay, start, cloud, jnp.asarray(init is None))
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
) -> SphereFit:
    """`fit_spheres` of many clouds of one size at once: one compiled, vmapped fit per chunk
    of `chunk_size` clouds (the last chunk padded), with a progress bar on stderr.

    centers (b, m, 3), radii (b, m); correspondences (m,) shared or (b, m), or None; `init`
    one pose for every cloud. Returns a `SphereFit` with a leading batch axis (NumPy
    arrays); a cloud whose fit fails has status FAILED and does not stop the others.
    """
    if not (isinstance(chunk_size, int) and chunk_size >= 1):
        raise ValueError(f"chunk_size: expected an integer >= 1, got {chunk_size!r}")
    template, lay, start, measured, match = _prepare(
        body, centers, radii, correspondences, fit, init, batch=True
    )
    total = measured.shape[0]
    chunk = min(chunk_size, total)
    bar = Progress(total, progress, "fit")
    outs = []
    for lo in range(0, total, chunk):
        rows = np.minimum(np.arange(lo, lo + chunk), total - 1)  # pad with the last cloud
        cloud = _cloud(
            template.lengths.dtype, measured[rows], None if match is None else match[rows]
        )
        out = _fit_many_jit(template, lay, start, cloud, jnp.asarray(init is None))
        outs.append(jax.tree.map(lambda a: np.asarray(a)[: min(chunk, total - lo)], out))
        bar.update(min(lo + chunk, total))
    out = jax.tree.map(lambda *a: np.concatenate(a), *outs)
    result = _result(body, template, out)
    return jax.tree.map(lambda a: np.asarray(a) if eqx.is_array(a) else a, result)
