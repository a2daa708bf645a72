"""Motion capture (docs/design.md, section 7): a body scaled and its markers registered on a static
trial (`scale_and_register`), then the posture of every frame of a trial (`fit_motion`).

Both are weighted least squares over the reach core's unknowns (`_unknowns`: swing vectors
and twists within their limits through bounded maps, the spine as its Bendspine target,
the whole body's placement free), solved by optimistix's Levenberg-Marquardt on Cholesky
normal equations, one walk per residual evaluation and closed-form Jacobians
(`_marker_kernel.tree_markers`). Only the segments that carry a marker, or hold one below
them, are walked and move (`mocap_layout`): the hands of a set without hand markers stay as
in the start. For the shipped set on the default body: 38 posture unknowns.

**The static fit** (`scale_and_register`). Unknowns: the posture, the logarithms of the
axial scale factors of the 13 `SCALE_GROUPS` (left and right share one; the radial ones
too with fit "radii") and every marker's offset. Residual rows, each a standard score:
- each marker, sqrt(weight) (model - measured) / `MARKER_SD`;
- each marker's move from where the set puts it on the scaled body (the set's offsets scale
  with the body, `scale_offsets`) / its tolerance: bony landmarks stay close, soft-tissue
  markers may move;
- the population prior (`prior=True`): the ANSUR II log-Gaussian of one sex
  (`PopulationPrior.ansur2`), marginalised to the measurements the scale factors decide
  (`PRIOR_MEASUREMENTS`; with the radii `RADIAL_MEASUREMENTS` too), whitened by its
  covariance, the measurements of the scaled body being the linear model of
  `_anthropometry` (exact within a piece); and each factor's spread `PROPORTION_SD` about
  the template's proportions, which the measurements do not fix (how the trunk splits
  between the lumbar and thoracic spine). So the answer is the maximum a posteriori body:
  the markers decide what they see, the population fills in the rest (the hands' length
  from the other lengths). Without the prior, a weak pull holds what no marker sees;
- a weak pull `PULL` of every posture unknown toward the start.
Start: the standard position moved rigidly (weighted Kabsch) so that the markers riding
rigidly on the whole body (the pelvis's) lie on the trial's mean frame.

**Every frame** (`fit_motion`). The body and offsets fixed, each frame's rows are
sqrt(weight) (model - measured) / `MARKER_SD` of its present markers (a missing marker
weighs 0 in its frame) and the pull toward the start moved rigidly onto the frame. The
frames are solved in order (`lax.scan`), each from its predecessor's answer. Measured on
the shipped walk (151 frames, 41 markers, float32, 2 shared CPU cores) in one harness: one
vmapped solve of all frames, each from the registered static pose moved rigidly onto the
frame's pelvis markers (up to 40 steps), with a second pass for the frames it left
unconverged from their nearest converged neighbour, took 7.9 s, and 92 of 151 frames
were still unconverged (the static pose holds the arms out sideways: they travel 80
degrees to the walking arms, and under vmap every frame runs as long as the slowest);
the scan took 2.4 s, all but one frame converged, mean marker RMS 19.9 mm against the
batch's 22.5 mm. The scan is kept; in one compiled call with the anchors, errors and
poses it takes 0.8-1.0 s (150-190 frames/s), median 12 solver steps a frame.
"""

import dataclasses
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float, Int

from .._body import Body, Pose, without_names
from .._progress import Progress
from ..anthropometry._prior import PopulationPrior
from ..anthropometry._scale_to import LENGTHS, linear_model_jit
from ..anthropometry._scaling import N_GROUPS, per_segment
from ..ik._problem import Problem, make_problem
from ._marker_points import MocapLayout, mocap_layout, model_markers, rigid_start, tree_markers
from ._markers import MarkerTrial
from ._markerset import MarkerSet, match_markers, scale_offsets
from ._sphere_fit import FitStatus, scaled

FIT_CHOICES = ("lengths", "radii", "offsets")
MARKER_SD = 0.01  # m: a marker's rows are its error in units of this
PULL = 1e-3  # per unit of a free variable: an unobserved direction weighs as 10 um of error
# The prior's spread of each group's scale factor around the template's proportions: the
# measurements see sums of lengths (stature), not how the trunk splits between the lumbar
# and the thoracic spine; segment proportions vary by a few per cent between people.
PROPORTION_SD = 0.1
# With the radii: the breadths and depths of ANSUR II that the radial factors decide.
RADIAL_MEASUREMENTS = ("bideltoidbreadth", "hipbreadth", "chestdepth", "headlength")
MIN_MARKERS = 3  # a frame with fewer present markers cannot be placed: FAILED
# The length measurements of ANSUR II that the axial scale factors decide (they carry at
# least 80 % of each: tests/fitting/test_mocap.py). Breadths, depths and the weight depend on the
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
LINEAR_SOLVER = lx.Normal(lx.Cholesky())
STATIC_STEPS = 100
FRAME_STEPS = 100


def _solver(dtype) -> optx.LevenbergMarquardt:
    """Levenberg-Marquardt, stopping once a step changes the unknowns by less than rtol
    relative (plus atol) and the residual rows by as little, both in root mean square over
    the entries: a limb straight at its stop (the knee, the elbow) sits where its bounded
    map is flat, and creeps there for many steps without changing the fit. In float32,
    1e-3: a thousandth of a radian turns a 40 cm segment by 0.4 mm, a tenth of the
    markers' noise. In float64 (tests), 1e-9."""
    tol = 1e-9 if jnp.finfo(dtype).bits == 64 else 1e-3
    return optx.LevenbergMarquardt(
        rtol=tol, atol=tol, norm=optx.rms_norm, linear_solver=LINEAR_SOLVER
    )


def _status(finite: Array, converged: Array) -> Array:
    return jnp.where(
        finite,
        jnp.where(converged, FitStatus.CONVERGED, FitStatus.NOT_CONVERGED),
        FitStatus.FAILED,
    )


# --- the static fit ----------------------------------------------------------------------------
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

    @property
    def converged(self) -> bool:
        return bool(self.status == FitStatus.CONVERGED)


class _Prior(eqx.Module):
    """The population prior's marginal of the measurements the fit changes, on the template
    scaled by axial and radial group factors s (2 n_group,): the measurements are A s,
    exactly within a piece (they are piecewise linear in the scale factors,
    `_anthropometry`), with their mean log values and whitening (the inverse Cholesky
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
    A = np.asarray(linear_model_jit(without_names(template), jnp.ones(2 * N_GROUPS, dtype)))
    arrays = (A[[LENGTHS.index(n) for n in names]], prior.mean[k], whiten)
    return _Prior(*(jnp.asarray(a, dtype) for a in arrays))


class _Static(eqx.Module):
    """The fixed part of the static fit."""

    problem: Problem  # the posture's problem on the template, from the aligned start
    markerset: MarkerSet  # the set's offsets on the template
    target: Float[Array, "n 3"]  # m, measured mean positions (0 where missing)
    sqrt_w: Float[Array, " n"]  # sqrt(weight) / MARKER_SD, 0 where missing
    prior: _Prior | None


def _static_state(static: _Static, lay: MocapLayout, z: Array):
    """The segment lengths (n_seg,) and marker offsets (n, 3) on the scaled body, the
    posture's free vector, the log scales and the offsets' moves, for the unknowns z."""
    x, log_axial, log_radial, moves = lay.split(z)
    template = static.problem.body
    axial = per_segment(template, jnp.exp(log_axial))
    radial = per_segment(template, jnp.exp(log_radial))
    offsets = scale_offsets(static.markerset, template, axial, radial).offsets
    return template.lengths * axial, offsets + moves, x, (log_axial, log_radial), moves


def _static_residuals(z: Array, args) -> Array:
    """The static fit's rows (module docstring), standard scores."""
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
    return jnp.concatenate(rows)


def _fit_static(template: Body, lay: MocapLayout, rest: Pose, static: _Static):
    """The static solve: the start moved rigidly onto the pelvis markers, then every unknown
    at once. Returns the pose, log axial scales, offsets, per-marker errors, status, steps."""
    present = static.sqrt_w > 0
    x0 = static.problem.x0
    p0 = model_markers(static.problem, lay, static.markerset.offsets, x0)
    root = rigid_start(lay, p0, static.target, present, static.problem.position0)
    init = static.problem.pose(x0.at[-6:].set(root), rest)
    static = dataclasses.replace(static, problem=make_problem(template, lay.pose, init))
    z0 = jnp.zeros(sum(lay.sizes), x0.dtype).at[: lay.sizes[0]].set(static.problem.x0)
    sol = optx.least_squares(
        _static_residuals, _solver(z0.dtype), z0, (static, lay), max_steps=STATIC_STEPS, throw=False
    )
    finite = jnp.all(jnp.isfinite(sol.value))
    z = jnp.where(finite, sol.value, z0)
    lengths, offsets, x, (log_axial, log_radial), _ = _static_state(static, lay, z)
    p = tree_markers(lay, static.problem, lengths, offsets, x)
    errors = jnp.where(present, jnp.linalg.norm(p - static.target, axis=-1), jnp.nan)
    status = _status(finite, sol.result == optx.RESULTS.successful)
    pose = static.problem.pose(x, init)
    return pose, log_axial, log_radial, offsets, errors, status, sol.stats["num_steps"]


_fit_static_jit = eqx.filter_jit(_fit_static)


def _fit_names(fit) -> tuple[str, ...]:
    fit = (fit,) if isinstance(fit, str) else tuple(fit)
    unknown = [f for f in fit if f not in FIT_CHOICES]
    if unknown:
        raise ValueError(
            f"scale_and_register: fit {unknown} is not a choice; give a subset of {FIT_CHOICES} "
            "(the posture always moves)"
        )
    return tuple(f for f in FIT_CHOICES if f in fit)


def _frame_arrays(trial: MarkerTrial, weights: np.ndarray, dtype) -> tuple[Array, Array]:
    """Targets (b, n, 3) m with NaN for a missing marker, and sqrt(weight) / MARKER_SD
    (b, n), 0 where missing."""
    pos = np.asarray(trial.positions, float)
    present = np.all(np.isfinite(pos), axis=-1)
    sqrt_w = np.where(present, np.sqrt(weights) / MARKER_SD, 0.0)
    return jnp.asarray(np.where(present[..., None], pos, np.nan), dtype), jnp.asarray(sqrt_w, dtype)


def _seen(target: Array) -> tuple[Array, Array]:
    """The targets with 0 for NaN (a row of weight 0 must not carry a NaN into the
    residuals) and whether each marker is present."""
    present = jnp.all(jnp.isfinite(target), axis=-1)
    return jnp.where(present[..., None], target, 0.0), present


def scale_and_register(
    body: Body,
    static: MarkerTrial,
    markerset: MarkerSet,
    *,
    prior=True,
    fit=("lengths", "offsets"),
    sex: str | None = None,
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
            On the shipped trials the radii bring the static errors down (the sternum's
            from 56 to 36 mm: the subject's chest is shallower than the template's) but not
            the walk's.
        sex: "male" or "female" for `prior=True` (default: "female" when the body's name
            starts with it, else "male").

    Returns:
        A `StaticFit`: the scaled body, the static pose, the registered marker set (offsets
        for the scaled body; only the markers the trial has), the scale factors, each
        marker's distance (m) from its measured position, a FitStatus.

    Raises:
        ValueError: an unknown choice in `fit`; no marker shared with the set; fewer than
            `MIN_MARKERS` markers present in the static trial.
    """
    fit = _fit_names(fit)
    markerset, static = match_markers(markerset, static.mean_frame())
    template = without_names(body)
    lay = mocap_layout(template, markerset, fit)
    dtype = template.lengths.dtype
    target, sqrt_w = _frame_arrays(static, np.asarray(markerset.weights, float), dtype)
    if int(np.sum(np.asarray(sqrt_w) > 0)) < MIN_MARKERS:
        raise ValueError(
            f"scale_and_register: the static trial {static.source!r} has fewer than "
            f"{MIN_MARKERS} markers of the set {markerset.name!r} present; the body cannot "
            "be placed"
        )
    rest = template.rest_pose()
    state = _Static(
        problem=_make_problem_jit(template, lay.pose, rest),
        markerset=markerset,
        target=_seen(target[0])[0],
        sqrt_w=sqrt_w[0],
        prior=population_prior(prior, body, sex, fit),
    )
    out = _fit_static_jit(template, lay, rest, state)
    pose, log_axial, log_radial, offsets, errors, status, steps = out
    scaled_body = scaled(body, log_axial, log_radial)
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
    )


# --- every frame -------------------------------------------------------------------------------
def _frame_residuals(x: Array, args) -> Array:
    problem, lay, offsets, target, sqrt_w, anchor = args
    p = model_markers(problem, lay, offsets, x)
    return jnp.concatenate([(sqrt_w[:, None] * (p - target)).ravel(), PULL * (x - anchor)])


def _solve_frame(problem, lay, offsets, x_start, anchor, target, sqrt_w):
    """One frame's posture from x_start, weakly pulled toward `anchor`: (x, status, steps).
    A frame with fewer than `MIN_MARKERS` markers keeps x_start (FAILED)."""
    sol = optx.least_squares(
        _frame_residuals,
        _solver(x_start.dtype),
        x_start,
        (problem, lay, offsets, target, sqrt_w, anchor),
        max_steps=FRAME_STEPS,
        throw=False,
    )
    ok = jnp.all(jnp.isfinite(sol.value)) & (jnp.sum(sqrt_w > 0) >= MIN_MARKERS)
    status = _status(ok, sol.result == optx.RESULTS.successful)
    return jnp.where(ok, sol.value, x_start), status, sol.stats["num_steps"]


def _fit_frames(problem, lay, offsets, measured, sqrt_w, x_first, init: Pose):
    """Every frame of a chunk, in order (lax.scan), each from its predecessor's answer,
    the first from x_first (NaN: from its anchor). Each frame's anchor is the start moved
    rigidly onto its rigid markers. Returns the poses, model markers, errors (NaN where
    missing), statuses, steps and the last free vector. measured: (b, n, 3), NaN where
    missing."""
    target, present = _seen(measured)
    p0 = model_markers(problem, lay, offsets, problem.x0)

    def anchor_of(t, w):
        root = rigid_start(lay, p0, t, w > 0, problem.position0)
        return problem.x0.at[-6:].set(root)

    anchor = jax.vmap(anchor_of)(target, sqrt_w)
    first = jnp.where(jnp.all(jnp.isfinite(x_first)), x_first, anchor[0])

    def step(x_prev, frame):
        x, status, steps = _solve_frame(problem, lay, offsets, x_prev, *frame)
        return x, (x, status, steps)

    last, (xs, status, steps) = jax.lax.scan(step, first, (anchor, target, sqrt_w))
    p = jax.vmap(lambda x: model_markers(problem, lay, offsets, x))(xs)
    errors = jnp.where(present, jnp.linalg.norm(p - target, axis=-1), jnp.nan)
    poses = jax.vmap(problem.pose, in_axes=(0, None))(xs, init)
    return poses, p, errors, status, steps, last


_fit_frames_jit = eqx.filter_jit(_fit_frames)
_make_problem_jit = eqx.filter_jit(make_problem)


class MotionFit(eqx.Module):
    """What `fit_motion` returns: NumPy arrays, frame axis first."""

    poses: Pose  # batched over frames (the spine as a Bendspine target)
    markers: Float[np.ndarray, "f n 3"]  # m, the model's markers
    errors: Float[np.ndarray, "f n"]  # m, model to measured; NaN where the marker was missing
    rms: Float[np.ndarray, " f"]  # m, root mean square of the present markers' errors
    max: Float[np.ndarray, " f"]  # m, the largest of them
    status: Int[np.ndarray, " f"]  # a FitStatus per frame
    steps: Int[np.ndarray, " f"]  # solver steps per frame
    times: Float[np.ndarray, " f"]  # s
    names: tuple[str, ...] = eqx.field(static=True)  # the markers, the set's order
    kinds: tuple[str, ...] = eqx.field(static=True)  # "anatomical" | "tracking"

    def pose(self, i: int) -> Pose:
        """Frame i's pose, as JAX arrays (ready for `forward`, `render`, ...)."""
        return jax.tree.map(lambda a: jnp.asarray(a[i]), self.poses)

    def per_marker(self) -> dict[str, tuple[float, float]]:
        """Per marker: (RMS over the frames that see it, largest error), m; NaN for a marker
        no frame sees."""
        rms, worst = _rms_max(self.errors, axis=0)
        return {n: (float(r), float(m)) for n, r, m in zip(self.names, rms, worst)}

    def summary(self) -> dict[str, float]:
        """Mean and largest per-frame RMS and the largest error (m) over all markers, and the
        RMS over all frames of the anatomical and of the tracking markers apart."""
        out = {
            "mean_rms": float(np.nanmean(self.rms)),
            "max_rms": float(np.nanmax(self.rms)),
            "max_error": float(np.nanmax(self.max)),
        }
        for kind in ("anatomical", "tracking"):
            cols = [k for k, c in enumerate(self.kinds) if c == kind]
            out[f"{kind}_rms"] = float(_rms_max(self.errors[:, cols].ravel(), axis=0)[0])
        return out


def _rms_max(errors: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """Root mean square and largest of the finite errors along an axis; NaN where none."""
    seen = np.isfinite(errors)
    count = seen.sum(axis=axis)
    squares = np.where(seen, errors, 0.0) ** 2
    rms = np.where(count > 0, np.sqrt(squares.sum(axis) / np.maximum(count, 1)), np.nan)
    worst = np.where(count > 0, np.where(seen, errors, -np.inf).max(axis), np.nan)
    return rms, worst


def _weights(markerset: MarkerSet, weights) -> np.ndarray:
    """(n,) the IK weight of each marker of the (matched) set."""
    if weights is None:
        return np.asarray(markerset.weights, float)
    if isinstance(weights, Mapping):
        unknown = [n for n in weights if n not in markerset.names]
        if unknown:
            raise KeyError(
                f"fit_motion: weights name markers the matched set lacks: {', '.join(unknown)}; "
                f"it has {', '.join(markerset.names)}"
            )
        w = np.asarray([float(weights.get(n, 0.0)) for n in markerset.names])
    else:
        w = np.asarray(weights, float)
        if w.shape != (markerset.n_markers,):
            raise ValueError(
                f"fit_motion: weights must be ({markerset.n_markers},) in the set's order or "
                f"a {{marker: weight}} mapping, got shape {w.shape}"
            )
    if not np.all(np.isfinite(w) & (w >= 0)) or not np.any(w > 0):
        raise ValueError("fit_motion: weights must be finite and >= 0, at least one > 0")
    return w


def _check_pose(pose: Pose, what: str) -> None:
    for name, leaf in (("position", pose.position), ("angles", pose.angles)):
        a = np.asarray(leaf)
        if not np.all(np.isfinite(a)):
            raise ValueError(
                f"fit_motion: {what}.{name} is not finite (entry "
                f"{tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])}); give a finite "
                "start pose, e.g. scale_and_register(...).pose"
            )


def fit_motion(
    body: Body,
    markerset: MarkerSet,
    trial: MarkerTrial,
    *,
    start: Pose,
    weights=None,
    progress: bool = False,
    chunk_size: int = 512,
) -> MotionFit:
    """The posture of every frame of a trial (module docstring).

    Args:
        body: the (scaled) body, e.g. `scale_and_register(...).body`.
        markerset: its registered marker set (`StaticFit.markerset`). Markers the trial
            lacks, or that the set does not map, are left out with a warning.
        trial: the marker trajectories; a marker missing in a frame (NaN) takes no part in
            that frame.
        start: the pose every frame starts from and is weakly pulled toward, moved rigidly
            onto the frame's pelvis markers (`StaticFit.pose`).
        weights: None (the set's IK weights), a {marker: weight} mapping (the markers it
            does not name weigh 0: OpenSim's IK tasks), or an (n,) array in the set's order.
        progress: a progress bar on stderr.
        chunk_size: frames per compiled call (the last chunk padded).

    Returns:
        A `MotionFit`: per frame the pose, the model markers, each marker's error (NaN where
        missing), RMS and largest error, a FitStatus (FAILED for a frame with fewer than
        `MIN_MARKERS` markers: its pose is the start's); per marker `per_marker()`.
    """
    markerset, trial = match_markers(markerset, trial)
    w = _weights(markerset, weights)
    _check_pose(start, "start")
    if not (isinstance(chunk_size, int) and chunk_size >= 1):
        raise ValueError(f"fit_motion: chunk_size must be an integer >= 1, got {chunk_size!r}")
    template = without_names(body)
    dtype = template.lengths.dtype
    lay = mocap_layout(template, markerset)
    problem = _make_problem_jit(template, lay.pose, start)
    offsets = jnp.asarray(markerset.offsets, dtype)
    target, sqrt_w = _frame_arrays(trial, w, dtype)
    total = trial.n_frames
    chunk = min(chunk_size, total)
    bar = Progress(total, progress, "frames")
    outs = []
    x_last = jnp.full(lay.pose.n_free, jnp.nan, dtype)
    for lo in range(0, total, chunk):
        rows = np.minimum(np.arange(lo, lo + chunk), total - 1)  # pad with the last frame
        out = _fit_frames_jit(problem, lay, offsets, target[rows], sqrt_w[rows], x_last, start)
        *out, x_last = out
        keep = min(chunk, total - lo)
        outs.append(jax.tree.map(lambda a: np.asarray(a)[:keep], tuple(out)))
        bar.update(lo + keep)
    poses, p, err, status, steps = jax.tree.map(lambda *a: np.concatenate(a), *outs)
    rms, worst = _rms_max(err, axis=1)
    return MotionFit(
        poses=poses,
        markers=p,
        errors=err,
        rms=rms,
        max=worst,
        status=status.astype(int),
        steps=steps.astype(int),
        times=np.asarray(trial.times, float),
        names=markerset.names,
        kinds=markerset.kinds,
    )
