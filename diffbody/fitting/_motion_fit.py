"""The posture of every frame of a marker trial (`fit_motion`; docs/design.md, section 7),
the body and its registered markers fixed (`scale_and_register`).

Each frame's rows (`_mocap_solver`): sqrt(weight) (model - measured) / `MARKER_SD` of its
present markers (a missing marker weighs 0 in its frame) and a weak `PULL` toward the start
moved rigidly onto the frame's pelvis markers. The frames are solved in order (`lax.scan`),
each from its predecessor's answer, a chunk of frames per compiled call
(`diffbody._batches.map_chunks`, the last answer carried to the next chunk).
Results are NumPy, frame axis first: poses, markers (f, n, 3) m, errors (f, n) m.
"""

import dataclasses
import warnings
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._batches import map_chunks
from .._body import Body, Pose, without_names
from .._joint_angles import angle_names, joint_angles
from .._solver import FitStatus, Solved, solve
from ._marker_layout import mocap_layout, rigid_start
from ._marker_points import model_markers
from ._marker_trial import MarkerTrial
from ._markerset import MarkerSet, MarkerWarning, match_markers
from ._mocap_solver import (
    MIN_MARKERS,
    OUTLIER_SCALES,
    PULL,
    frame_arrays,
    make_problem_jit,
    masked_targets,
    robust_rows,
    solver,
)
from ._motion_limits import LIMITS, motion_limits

FRAME_STEPS = 100
# The first frame's solves start far (the static pose, the standard position): more steps.
FIRST_FRAME_STEPS = 300
WIDE = 10.0  # the first of a frame's two solves runs at this many robust scales
# m: the robust loss's scale when no static fit gives one (`StaticFit.marker_scale`).
DEFAULT_SCALE = 0.03


def _frame_residuals(x: Array, args) -> Array:
    problem, lay, offsets, target, sqrt_w, anchor, scale = args
    p = model_markers(problem, lay, offsets, x)
    d = p - target
    rows = robust_rows(sqrt_w[:, None] * d, jnp.sum(d * d, axis=-1), scale)
    return jnp.concatenate([rows.ravel(), PULL * (x - anchor)])


def _solve_frame(problem, lay, offsets, scale, x_start, anchor, target, sqrt_w, steps=FRAME_STEPS):
    """One frame's posture from x_start, weakly pulled toward `anchor`: `Solved`. Graduated:
    first at `WIDE` times the robust scale, then at the scale from there (a marker the start
    leaves farther than a few scales off still pulls in the first solve: from a far start,
    the robust loss alone would give up on the very markers that must move). A frame with
    fewer than `MIN_MARKERS` markers keeps x_start (FAILED)."""
    enough = jnp.sum(sqrt_w > 0) >= MIN_MARKERS
    args = (problem, lay, offsets, target, sqrt_w, anchor, scale)
    wide = solve(
        _frame_residuals, solver(x_start.dtype), x_start, args[:-1] + (WIDE * scale,), steps, enough
    )
    out = solve(_frame_residuals, solver(x_start.dtype), wide.value, args, steps, enough)
    status = jnp.where(wide.status == FitStatus.FAILED, wide.status, out.status)
    return Solved(out.value, status, wide.steps + out.steps)


def _first_frame(problem, lay, offsets, scale, starts, anchor, target, sqrt_w):
    """The first frame from each of `starts` (k, n_free), moved rigidly onto its markers
    like the anchor: the answer of least robust cost (`Solved`, the steps of all)."""
    args = (problem, lay, offsets, target, sqrt_w, anchor, scale)

    def from_start(x):
        p = model_markers(problem, lay, offsets, x)
        x = x.at[-6:].set(rigid_start(lay, p, target, sqrt_w > 0, problem.position0))
        frame = (anchor, target, sqrt_w)
        x, status, steps = _solve_frame(problem, lay, offsets, scale, x, *frame, FIRST_FRAME_STEPS)
        cost = jnp.sum(_frame_residuals(x, args) ** 2)
        return x, status, steps, jnp.where(status == FitStatus.FAILED, jnp.inf, cost)

    xs, status, steps, cost = jax.vmap(from_start)(starts)
    best = jnp.argmin(cost)
    return Solved(xs[best], status[best], jnp.sum(steps))


def _fit_frames(problem, lay, offsets, scale, starts, measured, sqrt_w, x_first, init: Pose):
    """Every frame of a chunk, in order (lax.scan), each from its predecessor's answer,
    the first from x_first, or where it is NaN (the trial's first frame) from the best of
    `starts` (`_first_frame`). Each frame's anchor is the start moved rigidly onto its rigid
    markers. Returns the poses, model markers, errors (NaN where missing), statuses, steps
    and the last free vector. measured: (b, n, 3), NaN where missing."""
    target, present = masked_targets(measured)
    p0 = model_markers(problem, lay, offsets, problem.x0)

    def anchor_of(t, w):
        root = rigid_start(lay, p0, t, w > 0, problem.position0)
        return problem.x0.at[-6:].set(root)

    anchor = jax.vmap(anchor_of)(target, sqrt_w)
    frame = (anchor[0], target[0], sqrt_w[0])
    x0, status0, steps0 = jax.lax.cond(
        jnp.all(jnp.isfinite(x_first)),
        lambda: _solve_frame(problem, lay, offsets, scale, x_first, *frame),
        lambda: _first_frame(problem, lay, offsets, scale, starts, *frame),
    )

    def step(x_prev, frame):
        x, status, steps = _solve_frame(problem, lay, offsets, scale, x_prev, *frame)
        return x, (x, status, steps)

    rest = (anchor[1:], target[1:], sqrt_w[1:])
    last, (xs, status, steps) = jax.lax.scan(step, x0, rest)
    xs = jnp.concatenate([x0[None], xs])
    status = jnp.concatenate([status0[None], status])
    steps = jnp.concatenate([steps0[None], steps])
    p = jax.vmap(lambda x: model_markers(problem, lay, offsets, x))(xs)
    errors = jnp.where(present, jnp.linalg.norm(p - target, axis=-1), jnp.nan)
    poses = jax.vmap(problem.pose, in_axes=(0, None))(xs, init)
    return poses, p, errors, status, steps, last


_fit_frames_jit = eqx.filter_jit(_fit_frames)


class MotionFit(eqx.Module):
    """What `fit_motion` returns: NumPy arrays, frame axis first."""

    FLAG_SHARE = 0.05  # `flagged` names a marker that is an outlier in more of the frames

    poses: Pose  # batched over frames (the spine as a Bendspine target)
    markers: Float[np.ndarray, "f n 3"]  # m, the model's markers
    errors: Float[np.ndarray, "f n"]  # m, model to measured; NaN where the marker was missing
    rms: Float[np.ndarray, " f"]  # m, root mean square of the present markers' errors
    max: Float[np.ndarray, " f"]  # m, the largest of them
    status: Int[np.ndarray, " f"]  # a FitStatus per frame
    steps: Int[np.ndarray, " f"]  # solver steps per frame
    times: Float[np.ndarray, " f"]  # s
    outliers: Bool[np.ndarray, "f n"]  # farther than OUTLIER_SCALES * scale from the model
    scale: float = eqx.field(static=True)  # m, the robust loss's scale
    names: tuple[str, ...] = eqx.field(static=True)  # the markers, the set's order
    kinds: tuple[str, ...] = eqx.field(static=True)  # "anatomical" | "tracking"
    # The markers left out before the fit, with why (`MarkerTrial.dead`): "no data" or
    # "does not move".
    dead: tuple[tuple[str, str], ...] = eqx.field(static=True, default=())

    @property
    def outlier_distance(self) -> float:
        """m: the distance beyond which a marker is an outlier in its frame."""
        return OUTLIER_SCALES * self.scale

    def angles(self, body: Body) -> dict[str, np.ndarray]:
        """ISB joint angles of every frame (`joint_angles`), degrees, (f,) each; `body` is
        the body fitted (`StaticFit.body`)."""
        fn = jax.jit(jax.vmap(lambda pose: joint_angles(body, pose)))
        out = fn(self.poses)
        return {k: np.asarray(out[k]) for k in angle_names()}

    def pose(self, i: int) -> Pose:
        """Frame i's pose, as JAX arrays (ready for `forward`, `render`, ...)."""
        return jax.tree.map(lambda a: jnp.asarray(a[i]), self.poses)

    def per_marker(self) -> dict[str, tuple[float, float]]:
        """Per marker: (RMS over the frames that see it, largest error), m; NaN for a marker
        no frame sees."""
        rms, worst = _rms_max(self.errors, axis=0)
        return {n: (float(r), float(m)) for n, r, m in zip(self.names, rms, worst)}

    def flagged(self) -> dict[str, str]:
        """The faulty markers, with why: each one left out ("no data", "does not move"),
        each one missing in more than `FLAG_SHARE` of the frames ("missing in 10 % of
        frames": gaps, or zeros read as gaps) and each one an outlier in more than
        `FLAG_SHARE` of the frames that see it ("outlier in 12 % of frames")."""
        out = dict(self.dead)
        seen = np.isfinite(self.errors).sum(axis=0)
        missing = 1.0 - seen / max(len(self.times), 1)
        share = self.outliers.sum(axis=0) / np.maximum(seen, 1)
        for name, gone, s in zip(self.names, missing, share):
            if name in out:
                continue
            why = []
            if gone > self.FLAG_SHARE:
                why.append(f"missing in {100 * gone:.0f} % of frames")
            if s > self.FLAG_SHARE:
                why.append(f"outlier in {100 * s:.0f} % of frames")
            if why:
                out[name] = ", ".join(why)
        return out

    def summary(self) -> dict[str, float]:
        """Mean and largest per-frame RMS and the largest error (m) over all markers; the
        RMS over all frames and markers, and over the inliers alone (`outliers` left out);
        the RMS over all frames of the anatomical and of the tracking markers apart."""
        inliers = np.where(self.outliers, np.nan, self.errors)
        out = {
            "mean_rms": float(np.nanmean(self.rms)),
            "max_rms": float(np.nanmax(self.rms)),
            "max_error": float(np.nanmax(self.max)),
            "rms": float(_rms_max(self.errors.ravel(), axis=0)[0]),
            "inlier_rms": float(_rms_max(inliers.ravel(), axis=0)[0]),
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
    worst = np.where(count > 0, np.where(seen, errors, -np.inf).max(axis, initial=-np.inf), np.nan)
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
    scale: float | None = None,
    limits: str = "motion",
    progress: bool = False,
    chunk_size: int = 512,
) -> MotionFit:
    """The posture of every frame of a trial (module docstring).

    Args:
        body: the (scaled) body, e.g. `scale_and_register(...).body`.
        markerset: its registered marker set (`StaticFit.markerset`). Markers the trial
            lacks, or that the set does not map, are left out with a warning; so are the
            trial's dead markers (`MarkerTrial.dead`: no data in any frame, or still while
            the body moves), recorded in `MotionFit.dead`.
        trial: the marker trajectories; a marker missing in a frame (NaN) takes no part in
            that frame.
        start: the pose every frame starts from and is weakly pulled toward, moved rigidly
            onto the frame's pelvis markers (`StaticFit.pose`). The first frame also starts
            from the standard position and keeps the better answer (a T-pose static trial
            is a poor start for a walk).
        weights: None (the set's IK weights), a {marker: weight} mapping (the markers it
            does not name weigh 0: OpenSim's IK tasks, `read_ik_tasks`), or an (n,) array in
            the set's order.
        scale: m, the robust loss's scale (`robust_rows`; default `StaticFit.marker_scale`
            when given, else `DEFAULT_SCALE`): a marker farther than `OUTLIER_SCALES`
            scales from the model barely pulls and is recorded as an outlier.
        limits: "motion" (default): the anatomical maximum ranges (`motion_limits`);
            "body": the body's own, comfortable ranges.
        progress: a progress bar on stderr.
        chunk_size: frames per compiled call (the last chunk padded).

    Returns:
        A `MotionFit`: per frame the pose, the model markers, each marker's error (NaN where
        missing), RMS and largest error, the outliers, a FitStatus (FAILED for a frame with
        fewer than `MIN_MARKERS` markers: its pose is the start's); per marker
        `per_marker()`, the faulty ones `flagged()`.
    """
    markerset, trial = match_markers(markerset, trial)
    w = _weights(markerset, weights)
    dead = trial.dead()
    if dead:
        warnings.warn(
            f"trial {trial.source!r}: {len(dead)} marker(s) carry no measurement, left out: "
            + ", ".join(f"{n} ({why})" for n, why in dead.items()),
            MarkerWarning,
            stacklevel=2,
        )
        # Kept in the arrays with no weight and no data (errors NaN), so that a trial with
        # a dead marker reuses the compiled fit of the same marker set.
        out = np.isin(markerset.names, list(dead))
        if out.all():
            raise ValueError(f"fit_motion: every marker of the trial {trial.source!r} is dead")
        w = np.where(out, 0.0, w)
        positions = np.where(out[None, :, None], np.nan, trial.positions)
        trial = dataclasses.replace(trial, positions=positions)
    _check_pose(start, "start")
    scale = DEFAULT_SCALE if scale is None else float(scale)
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"fit_motion: scale must be a positive number of metres, got {scale!r}")
    if limits not in LIMITS:
        raise ValueError(f"fit_motion: limits must be one of {LIMITS}, got {limits!r}")
    if not (isinstance(chunk_size, int) and chunk_size >= 1):
        raise ValueError(f"fit_motion: chunk_size must be an integer >= 1, got {chunk_size!r}")
    template = without_names(motion_limits(body) if limits == "motion" else body)
    dtype = template.lengths.dtype
    lay = mocap_layout(template, markerset)
    problem = make_problem_jit(template, lay.pose, start)
    x_rest = make_problem_jit(template, lay.pose, template.rest_pose()).x0
    starts = jnp.stack([problem.x0, x_rest])
    offsets = jnp.asarray(markerset.offsets, dtype)
    target, sqrt_w = frame_arrays(trial, w, dtype)
    c = jnp.asarray(scale, dtype)

    def chunk_fit(x_last, target, sqrt_w):
        *out, x_last = _fit_frames_jit(
            problem, lay, offsets, c, starts, target, sqrt_w, x_last, start
        )
        return x_last, tuple(out)

    x_first = jnp.full(lay.pose.n_free, jnp.nan, dtype)
    chunk = min(chunk_size, trial.n_frames)
    _, (poses, p, err, status, steps) = map_chunks(
        chunk_fit, (target, sqrt_w), chunk=chunk, progress=progress, label="frames", carry=x_first
    )
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
        outliers=np.nan_to_num(err, nan=0.0) > OUTLIER_SCALES * scale,  # `outlier_distance`
        scale=scale,
        names=markerset.names,
        kinds=markerset.kinds,
        dead=tuple(dead.items()),
    )
