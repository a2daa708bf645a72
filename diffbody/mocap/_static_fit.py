"""Scaling a body and registering its markers on a static trial (`scale_and_register`;
docs/design.md, section 7).

Weighted least squares (`_mocap_solver`) over the posture of the marked segments, the log
axial (with fit "radii" also radial) scale factors of the 13 `SCALE_GROUPS` (left and right
share one) and each marker's offset. Rows, each a standard score: each marker's error (m) /
`MARKER_SD`; each offset's move from where the set puts it on the scaled body / its
tolerance; the ANSUR II prior of one sex on the measurements the factors decide
(`PRIOR_MEASUREMENTS`), whitened, and each factor's spread `PROPORTION_SD` (without the
prior, a weak pull on the factors); tape or caliper readings of the body's length
measurements, when given, each (modelled - read) / its standard deviation; a weak `PULL` of
the posture toward the start. Start: the standard position moved rigidly onto the markers
riding rigidly on the whole body. With a motion trial, a second solve from that answer fits
frames of the motion too (`_motion_registration`).
"""

import dataclasses
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._body import Body, Pose, without_names
from .._programs import compiled
from .._solver import FitStatus, solve
from ..anthropometry._prior import PopulationPrior
from ..anthropometry._scale_to import LENGTHS
from ..anthropometry._scaling import log_scaled, per_segment
from ..files._marker_trial import MarkerTrial
from ..files._markerset_file import MarkerSet
from ..problem._problem import Problem, make_problem
from ._marker_layout import MocapLayout, mocap_layout, rigid_start
from ._marker_points import model_markers, tree_markers
from ._markerset import MarkerWarning, match_markers, scale_offsets
from ._mocap_solver import (
    MIN_MARKERS,
    PULL,
    frame_arrays,
    make_problem_jit,
    make_solver,
    masked_targets,
    rest_start,
)
from ._motion_fit import fit_motion
from ._motion_limits import LIMITS, motion_limits
from ._motion_registration import (
    MOTION_FRAMES,
    Frames,
    motion_frame_count,
    motion_markers,
    sample_frames,
)
from ._tape_readings import TAPE_SD, Readings, measurement_model, tape_readings

FIT_CHOICES = ("lengths", "radii", "offsets")
# The prior's spread of each group's scale factor around the template's proportions: the
# measurements see sums of lengths (stature), not how the trunk splits between the lumbar
# and the thoracic spine; segment proportions vary by a few per cent between people.
PROPORTION_SD = 0.1
# With the radii: the breadths and depths of ANSUR II that the radial factors decide.
RADIAL_MEASUREMENTS = ("bideltoidbreadth", "hipbreadth", "chestdepth", "headlength")
# The length measurements of ANSUR II that the axial scale factors decide (they carry at
# least 80 % of each: tests/mocap/test_mocap.py). Breadths, depths and the weight depend on the
# radii and masses.
PRIOR_MEASUREMENTS = (
    "stature",
    "span",
    "acromialheight",
    "cervicaleheight",
    "sittingheight",
    "trochanterionheight",
    "kneeheightmidpatella",
    "lateralfemoralepicondyleheight",
    "tibialheight",
    "biacromialbreadth",
    "acromionradialelength",
    "radialestylionlength",
    "handlength",
    "footlength",
)
STATIC_STEPS = 100
# The motion fit's robust scale (`StaticFit.marker_scale`): this many times the static RMS
# (how far a registered marker sits from its measurement with nothing moving: skin, chest
# depth, marker placement), at least MIN_SCALE_M.
SCALE_PER_RMS = 2.5
MIN_SCALE_M = 0.01


class StaticFit(eqx.Module):
    """What `scale_and_register` returns."""

    body: Body  # the template scaled by the fitted factors
    pose: Pose  # the static posture (the spine as a Bendspine target)
    markerset: MarkerSet  # the registered offsets, for `body`
    axial: Float[Array, " n_group"]  # axial scale factors, `SCALE_GROUPS` order
    radial: Float[Array, " n_group"]  # radial scale factors (1 unless "radii" were fitted)
    errors: Float[Array, " n"]  # m, each marker's distance from its measured mean position
    status: Int[Array, ""]  # a FitStatus
    steps: Int[Array, ""]  # solver steps
    # Registered from the motion too (`motion=`): each of its frames' markers' distance
    # from its measurement (k, n) m, NaN where missing; None: the static trial alone.
    motion_errors: Float[Array, "k n"] | None = None
    # The motion's frames fitted, as (trial, frame) indices into `motion`.
    motion_frames: tuple[tuple[int, int], ...] = eqx.field(static=True, default=())

    @property
    def converged(self) -> bool:
        return bool(self.status == FitStatus.CONVERGED)

    @property
    def marker_scale(self) -> float:
        """m: the robust scale for `fit_motion` on this registration: `SCALE_PER_RMS` times
        the RMS of the static errors and the motion's frames' (on the shipped trials 30 mm,
        21 mm registered on the walk too), at least `MIN_SCALE_M`."""
        e = np.asarray(self.errors)
        if self.motion_errors is not None:
            e = np.concatenate([e, np.asarray(self.motion_errors).ravel()])
        rms = float(np.sqrt(np.mean(e[np.isfinite(e)] ** 2)))
        return max(SCALE_PER_RMS * rms, MIN_SCALE_M)


class _Prior(eqx.Module):
    """The population prior's marginal of the measurements the fit changes, on the template
    scaled by axial and radial group factors s (2 n_group,): the measurements are A s,
    exactly within a piece (they are piecewise linear in the scale factors,
    `anthropometry._scale_to`), with their mean log values and whitening (the inverse Cholesky
    factor of their covariance)."""

    A: Float[Array, "k two_n_group"]  # m per unit factor: axial columns, then radial
    mean: Float[Array, " k"]
    whiten: Float[Array, "k k"]

    def rows(self, log_axial: Array, log_radial: Array) -> Array:
        """The whitened deviations of the log measurements, and each factor's deviation
        from the template's proportions (`PROPORTION_SD`): standard scores."""
        log_s = jnp.concatenate([log_axial, log_radial])
        log_m = jnp.log(self.A @ jnp.exp(log_s))
        return jnp.concatenate([self.whiten @ (log_m - self.mean), log_s / PROPORTION_SD])


def population_prior(prior, template: Body, sex: str | None, fit=FIT_CHOICES) -> _Prior | None:
    """The prior of the static fit (None: none) on `PRIOR_MEASUREMENTS`, and
    `RADIAL_MEASUREMENTS` when the radii are fitted. `prior`: True (every ANSUR II
    subject of `sex`; by default the sex the template's name starts with, male otherwise),
    False, or a `PopulationPrior`."""
    if prior is False or prior is None:
        return None
    if prior is True:
        if sex is None:
            sex = "female" if template.name.startswith("female") else "male"
        prior = PopulationPrior.ansur2(sex)
    if not isinstance(prior, PopulationPrior):
        raise TypeError(
            f"scale_and_register: prior must be True, False or a PopulationPrior, got {prior!r}"
        )
    names = PRIOR_MEASUREMENTS + (RADIAL_MEASUREMENTS if "radii" in fit else ())
    k = prior.index(names)
    whiten = np.linalg.inv(np.linalg.cholesky(prior.cov[np.ix_(k, k)]))
    dtype = template.lengths.dtype
    A = measurement_model(template)
    arrays = (A[[LENGTHS.index(n) for n in names]], prior.mean[k], whiten)
    return _Prior(*(jax.device_put(np.asarray(a, dtype)) for a in arrays))


class _Static(eqx.Module):
    """The fixed part of the static fit."""

    problem: Problem  # the posture's problem on the template, from the aligned start
    markerset: MarkerSet  # the set's offsets on the template
    target: Float[Array, "n 3"]  # m, measured mean positions (0 where missing)
    sqrt_w: Float[Array, " n"]  # sqrt(weight) / MARKER_SD, 0 where missing
    prior: _Prior | None
    readings: Readings | None = None
    frames: Frames | None = None  # the motion's (`_motion_registration`)


def _static_state(static: _Static, lay: MocapLayout, z: Array):
    """The segment lengths (n_seg,) and marker offsets (n, 3) on the scaled body, the
    posture's free vector, the log scales and the offsets' moves, for the unknowns z
    ([`MocapLayout` order | the motion's frames' free vectors, when fitted])."""
    x, log_axial, log_radial, moves = lay.split(z[: sum(lay.sizes)])
    template = static.problem.body
    axial = per_segment(template, jnp.exp(log_axial))
    radial = per_segment(template, jnp.exp(log_radial))
    offsets = scale_offsets(static.markerset, template, axial, radial).offsets
    return template.lengths * axial, offsets + moves, x, (log_axial, log_radial), moves


def _frame_vectors(lay: MocapLayout, z: Array) -> Array:
    """The motion's frames' free vectors (k, n_free) of the unknowns z."""
    return z[sum(lay.sizes) :].reshape(-1, lay.pose.n_free)


def _static_residuals(z: Array, args) -> Array:
    """The static fit's rows (module docstring), standard scores; with the motion's frames,
    theirs too (`_motion_registration`)."""
    static, lay = args
    lengths, offsets, x, log_scales, moves = _static_state(static, lay, z)
    p = tree_markers(lay, static.problem, lengths, offsets, x)
    rows = [
        (static.sqrt_w[:, None] * (p - static.target)).ravel(),
        (moves / static.markerset.tolerances[:, None]).ravel()[: lay.sizes[3]],
        PULL * (x - static.problem.x0),
    ]
    if static.prior is not None:
        rows.append(static.prior.rows(*log_scales))
    else:
        rows.append(PULL * jnp.concatenate(log_scales))
    if static.readings is not None:
        rows.append(static.readings.rows(*log_scales))
    if static.frames is not None:
        rows.append(static.frames.rows(lay, lengths, offsets, _frame_vectors(lay, z)))
    return jnp.concatenate(rows)


def _fit_static(template: Body, lay: MocapLayout, rest: Pose, static: _Static):
    """The static solve: the start moved rigidly onto the pelvis markers, then every unknown
    at once. Returns the pose, log axial and radial scales, offsets, per-marker errors,
    status, steps and the unknowns."""
    present = static.sqrt_w > 0
    x0 = static.problem.x0
    p0 = model_markers(static.problem, lay, static.markerset.offsets, x0)
    root = rigid_start(lay, p0, static.target, present, static.problem.position0)
    init = static.problem.pose(x0.at[-6:].set(root), rest)
    static = dataclasses.replace(static, problem=make_problem(template, lay.pose, init))
    z0 = jnp.zeros(sum(lay.sizes), x0.dtype).at[: lay.sizes[0]].set(static.problem.x0)
    return _solved(lay, init, static, z0)


def _fit_with_motion(
    template: Body,
    lay: MocapLayout,
    init: Pose,
    static: _Static,
    z0: Array,
    poses: Pose,
    measured: Array,
    sqrt_w: Array,
    scale: Array,
):
    """The registration from the static trial and the motion's frames
    (`_motion_registration`): from the static fit's unknowns z0, its posture `init`, and
    the frames' postures `poses` (batched), measured markers (k, n, 3; NaN where missing),
    sqrt(weight) / MARKER_SD (k, n) and robust scale (m). Returns `_fit_static`'s and the
    frames' marker errors (k, n) m."""
    problems = jax.vmap(lambda pose: make_problem(template, lay.pose, pose))(poses)
    frames = Frames(problems, masked_targets(measured)[0], sqrt_w, scale)
    problem = make_problem(template, lay.pose, init)
    static = dataclasses.replace(static, problem=problem, frames=frames)
    z0 = jnp.concatenate([z0.at[: lay.sizes[0]].set(problem.x0), problems.x0.ravel()])
    out = _solved(lay, init, static, z0)
    lengths, offsets, *_ = _static_state(static, lay, out[-1])
    return out, frames.errors(lay, lengths, offsets, _frame_vectors(lay, out[-1]))


def _solved(lay: MocapLayout, init: Pose, static: _Static, z0: Array):
    """Solve the static fit (with the frames it carries) from z0; see `_fit_static`."""
    z, status, steps = solve(
        _static_residuals, make_solver(z0.dtype), z0, (static, lay), STATIC_STEPS
    )
    lengths, offsets, x, (log_axial, log_radial), _ = _static_state(static, lay, z)
    p = tree_markers(lay, static.problem, lengths, offsets, x)
    errors = jnp.where(static.sqrt_w > 0, jnp.linalg.norm(p - static.target, axis=-1), jnp.nan)
    pose = static.problem.pose(x, init)
    return pose, log_axial, log_radial, offsets, errors, status, steps, z


_fit_static_jit = compiled(_fit_static)
_fit_with_motion_jit = compiled(_fit_with_motion)


def _fit_names(fit) -> tuple[str, ...]:
    fit = (fit,) if isinstance(fit, str) else tuple(fit)
    unknown = [f for f in fit if f not in FIT_CHOICES]
    if unknown:
        raise ValueError(
            f"scale_and_register: fit {unknown} is not a choice; give a subset of {FIT_CHOICES} "
            "(the posture always moves)"
        )
    return tuple(f for f in FIT_CHOICES if f in fit)


def scale_and_register(
    body: Body,
    static: MarkerTrial,
    markerset: MarkerSet,
    *,
    prior=True,
    fit=("lengths", "offsets"),
    sex: str | None = None,
    limits: str = "motion",
    # Not annotated: a reading, a motion or a count of the wrong kind is told by
    # `tape_readings`, `sample_frames` and `motion_frame_count`, by name.
    measured=None,
    measured_sd=TAPE_SD,
    motion=None,
    motion_frames=MOTION_FRAMES,
) -> StaticFit:
    """Scale a body and register its markers on a static trial (module docstring).

    Args:
        body: the template (its markers' offsets are `markerset`'s, resolved for it).
        static: the static trial; its frames are averaged (`MarkerTrial.mean_frame`).
            Markers it lacks, or that the set does not map, are left out with a warning.
        markerset: the marker set resolved for `body` (`load_markerset`).
        prior: True: the ANSUR II population prior of `sex` on the body's length
            measurements (module docstring); a `PopulationPrior`; False: none.
        fit: what moves besides the posture, a subset of ("lengths", "radii", "offsets"):
            the log axial and radial scale factors of `SCALE_GROUPS`, each marker's offset.
            On the shipped trials the radii bring the static errors down (the subject's
            chest is shallower than the template's) but not the walk's (docs/benchmarks.md,
            "Anthropometry").
        sex: "male" or "female" for `prior=True` (default: "female" when the body's name
            starts with it, else "male").
        limits: "motion" (default): the anatomical maximum ranges (`motion_limits`), which
            the returned body carries; "body": the body's own.
        measured: tape or caliper readings beside the markers, measurement name -> metres
            (stature, span, segment lengths, breadths: `anthropometry._scale_to.LENGTHS`,
            measured as ANSUR II does, `diffbody.MEASUREMENTS`), e.g. {"stature": 1.78}.
            Each is a row (modelled - read) / `measured_sd` beside the markers and the
            prior; `diffbody.measurements(fit.body)` gives the fitted values.
        measured_sd: each reading's standard deviation (m; one for all, or by name):
            `TAPE_SD` (5 mm) by default.
        motion: a trial of the subject moving (or a list of trials): the scale factors and
            offsets are then fitted to `motion_frames` of its frames as well, spread evenly
            over it (`_motion_registration`): the body the motion shows, not the static
            posture's (on the shipped walk the walk's mean marker RMS falls from 18.7 to
            7.2 mm). None (default): the static trial alone.
        motion_frames: how many of the motion's frames (`MOTION_FRAMES`); 0: the static
            trial alone.

    Returns:
        A `StaticFit`: the scaled body, the static pose, the registered marker set (offsets
        for the scaled body; only the markers the trial has), the scale factors, each
        marker's distance (m) from its measured position, a FitStatus; with `motion`, the
        frames fitted and their markers' distances (`motion_frames`, `motion_errors`).

    Raises:
        ValueError: an unknown choice in `fit`; no marker shared with the set; fewer than
            `MIN_MARKERS` markers present in the static trial; a reading that is not a
            length in metres, or its standard deviation not > 0; motion_frames not an
            integer >= 0; no frame of the motion seeing `MIN_MARKERS` markers of the set.
        TypeError: motion not a MarkerTrial or a list of them.
        KeyError: an unknown measurement name (the valid ones listed).
    """
    fit = _fit_names(fit)
    readings = tape_readings(measured, body, measured_sd)
    motion_frames = motion_frame_count(motion_frames)
    if limits not in LIMITS:
        raise ValueError(f"scale_and_register: limits must be one of {LIMITS}, got {limits!r}")
    if limits == "motion":
        body = motion_limits(body)
    markerset, static = match_markers(markerset, static.mean_frame())
    template = without_names(body)
    lay = mocap_layout(template, markerset, fit)
    dtype = template.lengths.dtype
    target, sqrt_w = frame_arrays(static, np.asarray(markerset.weights, float), dtype)
    if int(np.sum(np.asarray(sqrt_w) > 0)) < MIN_MARKERS:
        raise ValueError(
            f"scale_and_register: the static trial {static.source!r} has fewer than "
            f"{MIN_MARKERS} markers of the set {markerset.name!r} present; the body cannot "
            "be placed"
        )
    rest = rest_start(template)
    state = _Static(
        problem=make_problem_jit(template, lay.pose, rest),
        markerset=markerset,
        target=masked_targets(target[0])[0],
        sqrt_w=sqrt_w[0],
        prior=population_prior(prior, body, sex, fit),
        readings=readings,
    )
    out = _fit_static_jit(template, lay, rest, state)
    first = _static_fit(body, markerset, out)
    if motion is None or not motion_frames:
        return first
    sampled, where = sample_frames(markerset, motion, motion_frames)
    with warnings.catch_warnings():  # the motion's markers are told when it is fitted
        warnings.simplefilter("ignore", MarkerWarning)
        starts = fit_motion(
            first.body,
            motion_markers(first.markerset, motion),
            sampled,
            start=first.pose,
            scale=first.marker_scale,
            limits=limits,
            velocity=False,  # the frames are spread over the motion, not consecutive
        )
    measured, sqrt_w = frame_arrays(sampled, np.asarray(markerset.weights, float), dtype)
    scale = jax.device_put(np.asarray(first.marker_scale, dtype))
    out, motion_errors = _fit_with_motion_jit(
        template, lay, first.pose, state, out[-1], starts.poses, measured, sqrt_w, scale
    )
    return _static_fit(body, markerset, out, motion_errors, where)


def _static_fit(body, markerset, out, motion_errors=None, where=()) -> StaticFit:
    """The `StaticFit` of a solve's outputs (`_solved`)."""
    pose, log_axial, log_radial, offsets, errors, status, steps, _ = out
    scaled_body = log_scaled(body, log_axial, log_radial)
    scaled_body = dataclasses.replace(
        scaled_body, name=f"{body.name}-scaled", source="diffbody.scale_and_register"
    )
    return StaticFit(
        body=scaled_body,
        pose=pose,
        markerset=eqx.tree_at(lambda m: m.offsets, markerset, offsets),
        axial=jnp.exp(log_axial),
        radial=jnp.exp(log_radial),
        errors=errors,
        status=status,
        steps=steps,
        motion_errors=motion_errors,
        motion_frames=where,
    )
