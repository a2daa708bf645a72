"""What the two motion-capture fits share (docs/design.md, section 7): a marker's rows in
units of `MARKER_SD`, the weak `PULL` on what no marker sees, the one least-squares solver
(`diffbody._solver`) with the fits' tolerances, and a trial's targets (b, n, 3) m with their
weights.

Both fits (`_static_fit`, `_motion_fit`) solve over the reach core's unknowns of the marked
segments (`mocap_layout`), one walk and one closed-form Jacobian per evaluation
(`tree_markers`).
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike

from .._body import Body, Pose
from .._programs import compiled
from .._solver import least_squares_solver, tolerance
from ..files._marker_trial import MarkerTrial
from ..problem._problem import make_problem

MARKER_SD = 0.01  # m: a marker's rows are its error in units of this
PULL = 1e-3  # per unit of a free variable: an unobserved direction weighs as 10 um of error
MIN_MARKERS = 3  # a frame with fewer present markers cannot be placed: FAILED
# The motion fit's robust loss (`robust_rows`): a marker farther than OUTLIER_SCALES of its
# scale from the model weighs under a tenth of a close one and is reported as an outlier.
OUTLIER_SCALES = 3.0


def make_solver(dtype) -> optx.LevenbergMarquardt:
    """The fits' Levenberg-Marquardt, stopping once a step changes the unknowns by less than
    the tolerance relative (plus as much absolute) and the residual rows by as little, both
    in root mean square over the entries. In float32, 1e-3: a thousandth of a radian turns a
    40 cm segment by 0.4 mm, a tenth of the markers' noise; a limb straight at its stop (the
    knee, the elbow), where its bounded map is flat, creeps for many steps without changing
    the fit. In float64, 1e-4: what no marker sees (the clavicles and the spine under a set
    without arm markers) is held by the `PULL` alone, a curvature of PULL^2 per unit, so
    the cost, resolved to its rounding eps * cost, places it only to
    sqrt(eps * cost) / PULL, about 1e-4 for a frame's cost of 100: a tighter tolerance is
    met on real data only by luck (docs/benchmarks.md, "Anthropometry"). Noiseless data
    converge quadratically, so they still reach a micrometre."""
    return least_squares_solver(tolerance(dtype, 1e-3, 1e-4), norm=optx.rms_norm)


def frame_arrays(trial: MarkerTrial, weights: np.ndarray, dtype) -> tuple[Array, Array]:
    """Targets (b, n, 3) m with NaN for a missing marker, and sqrt(weight) / MARKER_SD
    (b, n), 0 where missing."""
    pos = np.asarray(trial.positions, float)
    present = np.all(np.isfinite(pos), axis=-1)
    sqrt_w = np.where(present, np.sqrt(weights) / MARKER_SD, 0.0)
    # `device_put`: a `jnp.asarray` of a host array compiles a small program per shape.
    target = np.where(present[..., None], pos, np.nan).astype(dtype)
    return jax.device_put(target), jax.device_put(sqrt_w.astype(dtype))


def masked_targets(target: Array) -> tuple[Array, Array]:
    """The targets with 0 for NaN (a row of weight 0 must not carry a NaN into the
    residuals) and whether each marker is present."""
    present = jnp.all(jnp.isfinite(target), axis=-1)
    return jnp.where(present[..., None], target, 0.0), present


def robust_rows(rows: Array, squared: Array, scale: ArrayLike) -> Array:
    """Markers' rows (n, 3) scaled so that their squares sum to Cauchy's loss of each
    one's distance d, given d^2 (n,) m^2: |rows|^2 c^2 log(1 + d^2 / c^2) / d^2, c = scale
    (m). Close markers keep
    their rows (the factor is 1 - d^2 / 4 c^2 + ...); a marker off by decimetres, with a
    weight 1 / (1 + d^2 / c^2), barely pulls (its rows grow as log d, not d). Smooth with
    finite derivatives at d = 0."""
    s = squared / scale**2
    small = s < 1e-4
    s_safe = jnp.where(small, 1.0, s)
    factor = jnp.where(small, 1.0 - s / 4.0, jnp.sqrt(jnp.log1p(s_safe) / s_safe))
    return rows * factor[:, None]


make_problem_jit = compiled(make_problem)


def rest_start(body: Body) -> Pose:
    """The body's rest pose with its spine named as its Bendspine target (the rest angles'
    total, on the host): the structure of every other start of a fit (a fitted pose), so
    that one compiled `make_problem` serves them all. The same frames as the rest pose."""
    pose = body.rest_pose()
    if body.spine is None:
        return pose
    total = np.asarray(body.spine.rest).sum(0).astype(np.asarray(pose.angles).dtype)
    return dataclasses.replace(pose, spine_target=jax.device_put(total))
