"""The posture of every frame of a marker trial (`fit_motion`; docs/design.md, section 7),
the body and its registered markers fixed (`scale_and_register`).

Each frame's rows (`_mocap_solver`): sqrt(weight) (model - measured) / `MARKER_SD` of its
present markers (a missing marker weighs 0 in its frame) and a weak `PULL` toward the start
moved rigidly onto the frame's pelvis markers. The frames are solved in order (`lax.scan`),
each from its predecessor's answer, a chunk of frames per compiled call
(`diffbody.runs._batches.map_chunks`, the last answer carried to the next chunk), with a
small velocity term toward the previous frame's answer (`VELOCITY`; `velocity=False`: off).
Every call takes `CHUNK_FRAMES` frames (the last chunk padded with frames that see
nothing; the markers in name order inside), so one compiled fit serves every trial and the
registration's frames. Results are NumPy, frame axis first: poses, markers (f, n, 3) m,
errors (f, n) m.
"""

import dataclasses
import warnings
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._body import Body, Pose, without_names
from .._programs import compiled
from .._solver import FitStatus, Solved, solve
from ..files._marker_trial import MarkerTrial
from ..files._markerset_file import MarkerSet
from ..runs._batches import map_chunks
from ._marker_layout import mocap_layout, rigid_start
from ._marker_points import model_markers
from ._markerset import MarkerWarning, match_markers
from ._mocap_solver import (
    MIN_MARKERS,
    OUTLIER_SCALES,
    PULL,
    frame_arrays,
    make_problem_jit,
    make_solver,
    masked_targets,
    rest_start,
    robust_rows,
)
from ._motion_limits import LIMITS, motion_limits
from ._motion_result import MotionFit, rms_max

FRAME_STEPS = 100
WIDE = 10.0  # the first of a frame's two solves runs at this many robust scales
# m: the robust loss's scale when no static fit gives one (`StaticFit.marker_scale`).
DEFAULT_SCALE = 0.03
# Frames per compiled call: every trial's length shares one program. The scan costs the
# same per frame at any chunk; a padded frame costs no solve.
CHUNK_FRAMES = 64
# The velocity term (`fit_motion(velocity=True)`): a frame's rows VELOCITY (x - x_before) per
# unit of a free variable, x_before the previous frame's answer. Of postures that fit the
# markers about equally well it keeps the one nearest the previous frame's: registered on the
# shipped T-pose alone, the walk's left arm flipped by 105 degrees between two frames without
# it and moves at most 21 degrees a frame with it. A joint turning 0.1 rad between frames
# costs what 0.3 mm of one marker's error does: on the walk registered on the motion too,
# the mean marker RMS changes by 0.001 mm, a frame's by up to 0.17 mm.
VELOCITY = 0.3


def _frame_residuals(x: Array, args) -> Array:
    problem, lay, offsets, target, sqrt_w, anchor, scale, before, velocity = args
    p = model_markers(problem, lay, offsets, x)
    d = p - target
    rows = robust_rows(sqrt_w[:, None] * d, jnp.sum(d * d, axis=-1), scale)
    return jnp.concatenate([rows.ravel(), PULL * (x - anchor), velocity * (x - before)])


# Where a solve of `_fit_frames`' scan starts: the previous solve's answer, a given start
# (a first-frame try), the best try's answer (the first frame proper).
FROM_PREVIOUS, FROM_START, FROM_BEST = 0, 1, 2


def _fit_frames(
    problem, lay, offsets, scale, velocity, starts, measured, sqrt_w, x_first, init: Pose
):
    """Every frame of a chunk, in order, each from its predecessor's answer, in two solves:
    first at `WIDE` times the robust scale, then at the scale from there (graduated: from a
    far start the robust loss alone gives up on the very markers that must move; the first
    is skipped where no marker is past the outlier distance from the start). The
    chunk's first frame is first tried from each of `starts` (k, n_free), each moved
    rigidly onto the frame's markers (the trial's first frame; x_first NaN), or from x_first
    k times (a later chunk); the try of least robust cost starts the frame. Tries, stages
    and frames are the steps of one `lax.scan` over one traced solve. Each frame's anchor is
    the start moved rigidly onto its rigid markers; `velocity` weighs each frame's velocity
    rows (`VELOCITY`, or 0) against the previous frame's answer (the first frame of a trial
    has none). Returns the poses, model markers, errors
    (NaN where missing), statuses, steps (both stages', the tries' added to the first
    frame's) and the last free vector. measured: (b, n, 3), NaN where missing."""
    target, present = masked_targets(measured)
    p0 = model_markers(problem, lay, offsets, problem.x0)

    def anchor_of(t, w):
        root = rigid_start(lay, p0, t, w > 0, problem.position0)
        return problem.x0.at[-6:].set(root)

    def placed(x):
        p = model_markers(problem, lay, offsets, x)
        return x.at[-6:].set(rigid_start(lay, p, target[0], present[0], problem.position0))

    anchor = jax.vmap(anchor_of)(target, sqrt_w)
    k, b = starts.shape[0], len(target)
    carried = jnp.all(jnp.isfinite(x_first))
    tries = jnp.where(carried, x_first[None], jax.vmap(placed)(starts))
    # The scan's solves: k tries of frame 0, then the b frames, each in two stages.
    frame = np.repeat(np.concatenate([np.zeros(k, int), np.arange(b)]), 2)
    wide = np.tile([True, False], k + b)
    source = np.full(2 * (k + b), FROM_PREVIOUS)
    source[0 : 2 * k : 2] = FROM_START
    source[2 * k] = FROM_BEST
    try_end = np.zeros(2 * (k + b), bool)
    try_end[1 : 2 * k : 2] = True
    step_index = np.arange(2 * (k + b))
    start = np.minimum(step_index // 2, k - 1)
    # A frame's last stage, and whether it follows a frame (a chunk's first frame follows
    # the previous chunk's last, carried); the tries follow none.
    frame_end = (step_index >= 2 * k) & (step_index % 2 == 1)
    weight = velocity * ((step_index >= 2 * k + 2) | (carried & (step_index >= 2 * k)))
    inputs = (anchor[frame], target[frame], sqrt_w[frame], wide, source, try_end, start)
    steps_in = (*inputs, frame_end, weight)

    def step(carry, inputs):
        x_prev, x_best, best, before = carry
        anchor, target, sqrt_w, wide, source, try_end, start, frame_end, weight = inputs

        def args_at(c):  # the frame's residuals' arguments at robust scale c
            return (problem, lay, offsets, target, sqrt_w, anchor, c, before, weight)

        x0 = jnp.select([source == FROM_START, source == FROM_BEST], [tries[start], x_best], x_prev)
        # The wide stage only where the start leaves a marker past the outlier distance.
        d = model_markers(problem, lay, offsets, x0) - target
        far = (
            jnp.max(jnp.where(sqrt_w > 0, jnp.sum(d * d, axis=-1), 0.0))
            > (OUTLIER_SCALES * scale) ** 2
        )

        def solved() -> Solved:
            args = args_at(jnp.where(wide, WIDE * scale, scale))
            out = solve(_frame_residuals, make_solver(x0.dtype), x0, args, FRAME_STEPS)
            return Solved(out.value, out.status, out.steps.astype(jnp.int32))

        # A frame with too few markers (a gap, or the padding of a trial's last chunk)
        # keeps its start without a solve: FAILED.
        enough = jnp.sum(sqrt_w > 0) >= MIN_MARKERS
        kept = jnp.where(enough, FitStatus.CONVERGED, FitStatus.FAILED).astype(jnp.int32)
        skipped = Solved(x0, kept, jnp.int32(0))
        x, status, steps = jax.lax.cond((wide & ~far) | ~enough, lambda: skipped, solved)
        cost = jnp.where(
            status == FitStatus.FAILED, jnp.inf, jnp.sum(_frame_residuals(x, args_at(scale)) ** 2)
        )
        better = try_end & (cost < best)
        carry = (
            x,
            jnp.where(better, x, x_best),
            jnp.where(better, cost, best),
            jnp.where(frame_end, x, before),
        )
        return carry, (x, status, steps)

    inf = jnp.asarray(jnp.inf, tries.dtype)
    # Finite where unused (weight 0): x_first is NaN at a trial's start.
    before = jnp.where(carried, x_first, tries[0])
    carry = (tries[0], tries[0], inf, before)
    (last, *_), (xs, status, steps) = jax.lax.scan(step, carry, steps_in)
    xs, status = xs[2 * k + 1 :: 2], status[2 * k + 1 :: 2]
    steps = steps.reshape(k + b, 2).sum(axis=1)
    steps = steps[k:].at[0].add(jnp.sum(steps[:k]))
    p = jax.vmap(lambda x: model_markers(problem, lay, offsets, x))(xs)
    errors = jnp.where(present, jnp.linalg.norm(p - target, axis=-1), jnp.nan)
    poses = jax.vmap(problem.pose, in_axes=(0, None))(xs, init)
    return poses, p, errors, status, steps, last


_fit_frames_jit = compiled(_fit_frames)


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
    velocity=True,  # not annotated: a value of the wrong kind is told by name, below
    progress: bool = False,
    chunk_size: int = CHUNK_FRAMES,
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
        velocity: the velocity term (`VELOCITY`): of postures that fit a frame's markers
            equally well, the one nearest the previous frame's; False: off (each frame
            only starts from its predecessor's answer).
        progress: a progress bar on stderr.
        chunk_size: frames per compiled call (`CHUNK_FRAMES`; the last chunk padded).

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
    if not isinstance(velocity, (bool, np.bool_)):
        raise ValueError(f"fit_motion: velocity must be True or False, got {velocity!r}")
    if not (isinstance(chunk_size, int) and chunk_size >= 1):
        raise ValueError(f"fit_motion: chunk_size must be an integer >= 1, got {chunk_size!r}")
    template = without_names(motion_limits(body) if limits == "motion" else body)
    dtype = template.lengths.dtype
    # Inside the fit the markers go in name order: the same set in any order (the trial's,
    # `select(walk.names)`; the set's, `match_markers`) is one compiled fit.
    order = np.argsort(markerset.names)
    fitted = markerset.select([markerset.names[i] for i in order])
    lay = mocap_layout(template, fitted)
    problem = make_problem_jit(template, lay.pose, start)
    x_rest = make_problem_jit(template, lay.pose, rest_start(template)).x0
    starts = jnp.stack([problem.x0, x_rest])
    offsets = jax.device_put(np.asarray(fitted.offsets, dtype))
    arrays = frame_arrays(trial.select(fitted.names), w[order], dtype)
    target, sqrt_w = (np.asarray(a) for a in arrays)
    c = jnp.asarray(scale, dtype)
    # Data, not structure: the velocity term on or off is one compiled fit.
    weight = jax.device_put(np.asarray(VELOCITY if velocity else 0.0, dtype))

    def chunk_fit(x_last, target, sqrt_w):
        *out, x_last = _fit_frames_jit(
            problem, lay, offsets, c, weight, starts, target, sqrt_w, x_last, start
        )
        return x_last, tuple(out)

    x_first = jnp.full(lay.pose.n_free, jnp.nan, dtype)
    # Every call solves `chunk_size` frames, the last chunk padded with frames that see
    # nothing (skipped): one compiled fit serves every trial length, and the registration's
    # frames (`scale_and_register(motion=)`).
    n = trial.n_frames
    pad = -n % chunk_size
    target = np.concatenate([target, np.full((pad, *target.shape[1:]), np.nan, dtype)])
    sqrt_w = np.concatenate([sqrt_w, np.zeros((pad, sqrt_w.shape[1]), dtype)])
    _, out = map_chunks(
        chunk_fit,
        (target, sqrt_w),
        chunk=chunk_size,
        progress=progress,
        label="mocap",
        unit="frame",
        carry=x_first,
    )
    poses, p, err, status, steps = jax.tree.map(lambda a: a[:n], out)
    back = np.argsort(order)  # the set's order again
    p, err = p[:, back], err[:, back]
    rms, worst = rms_max(err, axis=1)
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
