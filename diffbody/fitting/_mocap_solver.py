"""What the two motion-capture fits share (docs/design.md, section 7): a marker's rows in
units of `MARKER_SD`, the weak `PULL` on what no marker sees, Levenberg-Marquardt on Cholesky
normal equations with its `FitStatus`, and a trial's targets (b, n, 3) m with their weights.

Both fits (`_static_fit`, `_motion_fit`) solve over the reach core's unknowns of the marked
segments (`mocap_layout`), one walk and one closed-form Jacobian per evaluation
(`tree_markers`).
"""

import equinox as eqx
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array

from .._solver import FitStatus
from ..ik._problem import make_problem
from ._marker_trial import MarkerTrial

MARKER_SD = 0.01  # m: a marker's rows are its error in units of this
PULL = 1e-3  # per unit of a free variable: an unobserved direction weighs as 10 um of error
MIN_MARKERS = 3  # a frame with fewer present markers cannot be placed: FAILED
LINEAR_SOLVER = lx.Normal(lx.Cholesky())


def solver(dtype) -> optx.LevenbergMarquardt:
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


def fit_status(finite: Array, converged: Array) -> Array:
    """The `FitStatus` of a solve: FAILED where not finite, else whether it converged."""
    return jnp.where(
        finite,
        jnp.where(converged, FitStatus.CONVERGED, FitStatus.NOT_CONVERGED),
        FitStatus.FAILED,
    )


def frame_arrays(trial: MarkerTrial, weights: np.ndarray, dtype) -> tuple[Array, Array]:
    """Targets (b, n, 3) m with NaN for a missing marker, and sqrt(weight) / MARKER_SD
    (b, n), 0 where missing."""
    pos = np.asarray(trial.positions, float)
    present = np.all(np.isfinite(pos), axis=-1)
    sqrt_w = np.where(present, np.sqrt(weights) / MARKER_SD, 0.0)
    return jnp.asarray(np.where(present[..., None], pos, np.nan), dtype), jnp.asarray(sqrt_w, dtype)


def masked_targets(target: Array) -> tuple[Array, Array]:
    """The targets with 0 for NaN (a row of weight 0 must not carry a NaN into the
    residuals) and whether each marker is present."""
    present = jnp.all(jnp.isfinite(target), axis=-1)
    return jnp.where(present[..., None], target, 0.0), present


make_problem_jit = eqx.filter_jit(make_problem)
