"""Fitting a posture and a body's dimensions to a measured sphere cloud (`fit_spheres`,
`fit_spheres_batch`; docs/design.md, section 7): the host's checks, the start search's
candidates (`_cloud_start`) and the plain start annealed side by side (`_annealing`), the
result as a `SphereFit`.
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
from .._solver import FitStatus
from .._spine import spine_angles
from ..anthropometry._scaling import log_scaled_many
from ..runs._batches import chunk_rows, map_chunks
from ..runs._chunk_store import ChunkStore, float_name, input_hash
from ..runs._header import body_fields
from ..runs._streaming import tree_hash
from ._annealing import INLIER_DISTANCE, Fitted, fit_cloud, fit_from_starts, landed_by
from ._cloud_residuals import (
    FIT_NAMES,
    Cloud,
    FitLayout,
    fit_layout,
    make_start,
)
from ._cloud_start import search_start, search_tables
from ._clouds import check_correspondences, check_spheres

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
        # A host row is put on the device as it is: `jnp.asarray` compiles a small program
        # per shape.
        row = lambda a: jax.device_put(a[i]) if isinstance(a, np.ndarray) else a[i]  # noqa: E731
        return jax.tree.map(lambda a: row(a) if eqx.is_array(a) else a, self)


# --- the fit -------------------------------------------------------------------------------
def searched(template: Body, lay: FitLayout, init: Pose, cloud: Cloud, tables) -> Pose:
    """The `_cloud_start.search_start` candidates for `init` (the standard position) on the
    cloud, one per heading, best first: a pose with a leading axis of `YAWS`."""
    rest = make_start(template, lay, init)
    xs, _ = search_start(rest, lay, cloud, tables)
    return jax.vmap(lambda x: rest.problem.pose(x, init))(xs)


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
    """A chunk of clouds' fits: `fit_cloud` of each from `init`, or, when `tables` (static)
    is not None, from the searched starts and `init` moved onto the cloud
    (`fit_from_starts`). The searches run one after the other (`lax.map`: a vmap of the
    search's vmapped candidates trips XLA's dot simplifier, and one search already fills
    the cores), the fits vmapped."""
    if tables is None:
        fit = eqx.filter_vmap(fit_cloud, in_axes=(None, None, None, 0, None))
        return fit(template, lay, init, clouds, jnp.asarray(align))
    found = jax.lax.map(lambda c: searched(template, lay, init, c, tables), clouds)
    return jax.vmap(lambda f, c: _from_starts(template, lay, f, init, c))(found, clouds)


# One compiled fit per (body structure, layout, cloud size, start, chunk): a single cloud is
# a chunk of one, so `fit_spheres` and a batch of chunk_size=1 share their program, and every
# chunk size is traced once (the clouds' axis symbolic: `_programs.compiled`).
_fit_many_jit = compiled(fit_many, rows=(3,))


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


def _result(body: Body, template: Body, out: Fitted) -> SphereFit:
    """The `SphereFit` of a batch's fits (host arrays)."""
    # Named before scaling: a batch of bodies is no valid argument of Body's constructor.
    name = dict(name=f"{body.name}-fitted", source="diffbody.fit_spheres")
    template = dataclasses.replace(template, **name)
    return SphereFit(
        body=log_scaled_many(template, out.log_axial, out.log_radial),
        pose=out.pose,
        axial=np.exp(out.log_axial),
        radial=np.exp(out.log_radial),
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
    args = _prepare(body, centers, radii, correspondences, fit, init, batch=False)
    template, lay, start, measured, match, tables = args
    match = None if match is None else match[None]
    one = _fit_chunks(body, (template, lay, start, measured[None], match, tables), init, 1)
    return one.item(0)


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
    prepared = _prepare(body, centers, radii, correspondences, fit, init, batch=True)
    measured = prepared[3]
    chunk = chunk_rows(chunk_size, measured.shape[0])
    store = None
    if out is not None:
        given = input_hash(centers, radii, correspondences)
        settings = {"function": "fit_spheres_batch", "clouds": given, "fit": " ".join(fit)}
        settings |= dict(body_fields(body)) | {
            "init": "(none)" if init is None else tree_hash(init)
        }
        store = ChunkStore.open(out, settings | {"float": float_name()}, chunk, resume)
    return _fit_chunks(body, prepared, init, chunk, progress, store)


def _fit_chunks(body, prepared, init, chunk: int, progress=False, store=None) -> SphereFit:
    """`_prepare`'s clouds (b, m, 4) fitted in chunks of `chunk` rows (`map_chunks`), the
    result's arrays NumPy."""
    template, lay, start, measured, match, tables = prepared
    dtype = template.lengths.dtype
    none = np.full(measured.shape[:-1], -1, np.int32)
    known = match is not None

    def run(measured, match):
        cloud = Cloud(measured=measured.astype(dtype), match=match, known=known)
        return _fit_many_jit(template, lay, start, cloud, init is None, tables)

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
