"""The posture of every frame of a marker trial (`fit_motion`; docs/design.md, section 7),
the body and its registered markers fixed (`scale_and_register`).

Each frame's rows (`_mocap_solver`): sqrt(weight) (model - measured) / `MARKER_SD` of its
present markers (a missing marker weighs 0 in its frame) and a weak `PULL` toward the start
moved rigidly onto the frame's pelvis markers. The frames are solved in order (`lax.scan`),
each from its predecessor's answer, a chunk of frames per compiled call
(`diffbody._batches.map_chunks`, the last answer carried to the next chunk).
Results are NumPy, frame axis first: poses, markers (f, n, 3) m, errors (f, n) m.
"""

from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._batches import map_chunks
from .._body import Body, Pose, without_names
from .._solver import solve
from ._marker_layout import mocap_layout, rigid_start
from ._marker_points import model_markers
from ._marker_trial import MarkerTrial
from ._markerset import MarkerSet, match_markers
from ._mocap_solver import (
    MIN_MARKERS,
    PULL,
    frame_arrays,
    make_problem_jit,
    masked_targets,
    solver,
)

FRAME_STEPS = 100


def _frame_residuals(x: Array, args) -> Array:
    problem, lay, offsets, target, sqrt_w, anchor = args
    p = model_markers(problem, lay, offsets, x)
    return jnp.concatenate([(sqrt_w[:, None] * (p - target)).ravel(), PULL * (x - anchor)])


def _solve_frame(problem, lay, offsets, x_start, anchor, target, sqrt_w):
    """One frame's posture from x_start, weakly pulled toward `anchor`: (x, status, steps).
    A frame with fewer than `MIN_MARKERS` markers keeps x_start (FAILED)."""
    args = (problem, lay, offsets, target, sqrt_w, anchor)
    enough = jnp.sum(sqrt_w > 0) >= MIN_MARKERS
    return solve(_frame_residuals, solver(x_start.dtype), x_start, args, FRAME_STEPS, enough)


def _fit_frames(problem, lay, offsets, measured, sqrt_w, x_first, init: Pose):
    """Every frame of a chunk, in order (lax.scan), each from its predecessor's answer,
    the first from x_first (NaN: from its anchor). Each frame's anchor is the start moved
    rigidly onto its rigid markers. Returns the poses, model markers, errors (NaN where
    missing), statuses, steps and the last free vector. measured: (b, n, 3), NaN where
    missing."""
    target, present = masked_targets(measured)
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
    problem = make_problem_jit(template, lay.pose, start)
    offsets = jnp.asarray(markerset.offsets, dtype)
    target, sqrt_w = frame_arrays(trial, w, dtype)

    def chunk_fit(x_last, target, sqrt_w):
        *out, x_last = _fit_frames_jit(problem, lay, offsets, target, sqrt_w, x_last, start)
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
        names=markerset.names,
        kinds=markerset.kinds,
    )
