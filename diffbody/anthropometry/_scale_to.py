"""Scaling a body to measurements (docs/design.md, section 7): `scale_to`, `scale_to_percentile`,
`scale_population`.

Unknowns: the axial and radial factors of the 13 `SCALE_GROUPS` (26), by optimistix's
Gauss-Newton. Residuals, as relative deviations m / target - 1: the given measurements
(`GIVEN_SD`), the others against their conditional median under the `PopulationPrior`,
whitened, and each factor against 1 (`TEMPLATE_PULL`). Masses follow the given weight, or its
conditional median. Every length is piecewise linear in the factors, so within a piece the
lengths are A s exactly (`linear_model_jit`: one `jax.jacfwd`) and each person's solve is linear
least squares; an answer that leaves its piece is solved again with A recomputed there.
Lengths in m, weight in kg.
"""

import dataclasses
import os
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import ArrayLike

from .._body import Body, without_names
from ..files._body_file import load_body
from ..runs._batches import map_chunks
from ..runs._chunk_store import ChunkStore, input_hash
from ..runs._header import body_fields
from ._measurements import MEASUREMENT_NAMES, UNITS, check_names, measure
from ._prior import PopulationPrior, ansur2_subjects, check_sex
from ._scaling import N_GROUPS, per_segment, scale_body

GIVEN_SD = 1e-5  # log units: a given measurement is reproduced to 1e-5 relative
TEMPLATE_PULL = 1e-3  # weight of each scale factor's pull toward the template's (1)
MAX_SD = 6.0  # a given measurement further from its conditional mean is refused
LENGTHS = tuple(n for n in MEASUREMENT_NAMES if UNITS[n] == "m")


class _Args(NamedTuple):
    """One person's problem, all arrays, so one compiled solve serves every set of known
    measurements: a mask says which lengths are given."""

    A: jax.Array  # (L, 2 n_group): the lengths are A @ s within the current piece
    given: jax.Array  # (L,) bool: the lengths given
    log_target: jax.Array  # (L,) the given values, elsewhere the conditional means
    whiten: jax.Array  # (L, L) the conditional whitening of the others, zero on given rows


def scaled_body(template: Body, log_scales: ArrayLike, total_mass=None) -> Body:
    """The template with group scale factors exp(log_scales) ((2, n_group): axial, radial)."""
    s = jnp.exp(log_scales)
    return scale_body(
        template,
        per_segment(template, s[0]),
        per_segment(template, s[1]),
        total_mass=total_mass,
    )


def _lengths(template: Body, scales: jax.Array) -> jax.Array:
    """(L,) the length measurements of the template scaled by group factors (2, n_group)."""
    s = jnp.reshape(scales, (2, N_GROUPS))
    return measure(
        scale_body(template, per_segment(template, s[0]), per_segment(template, s[1])), LENGTHS
    )


def _linear_model(template: Body, scales: jax.Array) -> jax.Array:
    """A (L, 2 n_group): d lengths / d scales at `scales` (2 n_group,); exact within a piece
    (module docstring)."""
    return jax.jacfwd(_lengths, argnums=1)(template, scales)


def _residuals(scales: jax.Array, args: _Args) -> jax.Array:
    # Relative deviations m / target - 1: the logarithms' deviations to second order, and
    # linear in the scales, so that the whole problem is linear within a piece.
    d = (args.A @ scales) * jnp.exp(-args.log_target) - 1.0
    given = jnp.where(args.given, d / GIVEN_SD, 0.0)
    soft = args.whiten @ jnp.where(args.given, 0.0, d)
    return jnp.concatenate([given, soft, TEMPLATE_PULL * (scales - 1.0)])


def _solve(args: _Args, y0: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Scale factors (2 n_group,) from y0, and whether optimistix converged. The problem is
    linear least squares within a piece: Gauss-Newton solves it in its first step and
    confirms in the second."""
    tol = 1e-10  # float64 (`_solve_people`)
    sol = optx.least_squares(
        _residuals, optx.GaussNewton(rtol=tol, atol=tol), y0, args, max_steps=10, throw=False
    )
    ok = (sol.result == optx.RESULTS.successful) & jnp.all(sol.value > 0)
    return sol.value, ok


_solve_many_jit = jax.jit(jax.vmap(_solve))
linear_model_jit = eqx.filter_jit(_linear_model)
_lengths_many_jit = eqx.filter_jit(eqx.filter_vmap(_lengths, in_axes=(None, 0)))
PIECE_TOL = 1e-9  # relative: an answer whose exact lengths differ more left its piece


def _solve_rows(
    template: Body, args: _Args, y0: np.ndarray, chunk: int, progress: bool, store=None
) -> tuple:
    """Solve every row (leading axis of the row-wise fields) in chunks, then re-solve the
    rows whose answer left the linear model's piece with A recomputed there (module
    docstring). Returns scales (n, 2 n_group), converged (n,) and the exact lengths. The
    first pass over all rows keeps its chunks in `store` (a `ChunkStore`) when given."""
    dtype = args.log_target.dtype
    n = y0.shape[0]
    A = np.broadcast_to(np.asarray(args.A), (n,) + args.A.shape[-2:]).copy()
    log_target = np.asarray(args.log_target)

    def solve_chunk(A, log_target, y0):
        rows = A.shape[0]
        part = _Args(
            jnp.asarray(A, dtype),
            jnp.broadcast_to(args.given, (rows,) + args.given.shape[-1:]),
            jnp.asarray(log_target, dtype),
            jnp.broadcast_to(args.whiten, (rows,) + args.whiten.shape[-2:]),
        )
        xs, oks = _solve_many_jit(part, jnp.asarray(y0, dtype))
        return xs, oks, _lengths_many_jit(template, xs)

    x, ok, exact = np.zeros_like(y0), np.zeros(n, bool), np.zeros((n, A.shape[1]))
    rows = np.arange(n)
    for attempt in range(4):
        x[rows], ok[rows], exact[rows] = map_chunks(
            solve_chunk,
            (A[rows], log_target[rows], y0[rows]),
            chunk=chunk,
            progress=progress and attempt == 0,
            label="scale",
            unit="person",
            store=store if attempt == 0 else None,
        )
        linear = np.einsum("nij,nj->ni", A[rows], x[rows])
        off = np.max(np.abs(exact[rows] / linear - 1), axis=1) > PIECE_TOL
        rows = rows[off]
        if not len(rows):
            break
        for i in rows:  # few: another sphere at an extent
            A[i] = np.asarray(linear_model_jit(template, jnp.asarray(x[i], dtype)))
        y0 = x
    return x, ok & ~np.isin(np.arange(n), rows), exact


def _solve_people(
    template: Body, given, target, whiten, chunk: int, progress: bool = False, store=None
) -> tuple:
    """Log group scales (n, 2, n_group), converged (n,) and exact lengths (n, L) for rows
    of log targets (n, L), each started from the template scaled uniformly to its stature.

    Runs in float64 whatever the global setting: the given rows weigh 1e5 times the soft
    ones, a conditioning float32 cannot carry to the 1e-5 the given values are held to (in
    float32 a tenth of the people missed a given value by over a millimetre)."""
    with jax.enable_x64(True):
        # Names are static but no input of the measurements: without them every body of
        # one structure (both sexes, any scaled body) shares the compiled functions.
        template = jax.tree.map(
            lambda x: x.astype(jnp.float64) if eqx.is_inexact_array(x) else x,
            without_names(template),
        )
        target = np.atleast_2d(target)
        ones = jnp.ones(2 * N_GROUPS)
        A = linear_model_jit(template, ones)
        log_stature = float(np.log(np.asarray(A @ ones)[LENGTHS.index("stature")]))
        column = target[:, LENGTHS.index("stature")][:, None]
        y0 = np.exp(np.repeat(column, 2 * N_GROUPS, 1) - log_stature)
        args = _Args(A, jnp.asarray(given), jnp.asarray(target), jnp.asarray(whiten, jnp.float64))
        x, ok, exact = _solve_rows(template, args, y0, min(chunk, len(target)), progress, store)
    return np.log(np.maximum(x, 1e-12)).reshape(-1, 2, N_GROUPS), ok, exact


def _template(body: Body | None, sex: str) -> Body:
    return load_body(variant=f"{sex}50") if body is None else body


def _prior(prior: PopulationPrior | None, sex: str | None) -> PopulationPrior:
    if prior is None:
        if sex is None:
            raise ValueError("give sex='male' or sex='female' (or a PopulationPrior)")
        return _default_prior(check_sex(sex))
    if sex is not None and prior.sex != sex:
        raise ValueError(f"sex {sex!r} differs from the prior's sex {prior.sex!r}")
    return prior


_PRIORS: dict[str, PopulationPrior] = {}


def _default_prior(sex: str) -> PopulationPrior:
    if sex not in _PRIORS:
        _PRIORS[sex] = PopulationPrior.ansur2(sex)
    return _PRIORS[sex]


def _check_values(measurements: dict) -> dict[str, float]:
    check_names(measurements)
    out = {}
    for name, value in measurements.items():
        unit = UNITS[name]
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{name}: must be a number in {unit}, got {value!r}") from None
        if not np.isfinite(v) or v <= 0:
            raise ValueError(f"{name}: must be a finite number > 0 {unit}, got {value!r}")
        if unit == "m" and v > 10:
            raise ValueError(f"{name} = {v:g} m: lengths are in metres (was it millimetres?)")
        out[name] = v
    return out


def _conditioned(prior: PopulationPrior, known: tuple[str, ...], log_known: np.ndarray):
    """The given mask, the log targets (..., L) of the lengths and their whitening (L, L),
    for rows of known log values (..., k); and the log weight target (...,)."""
    c = prior.conditional(known)
    mean = c.unknown_mean(log_known)  # (..., u)
    given = np.asarray([n in known for n in LENGTHS])
    target = np.zeros(np.shape(log_known)[:-1] + (len(LENGTHS),))
    for j, n in enumerate(LENGTHS):
        target[..., j] = (
            log_known[..., known.index(n)] if given[j] else mean[..., c.unknown.index(n)]
        )
    soft = [j for j, g in enumerate(given) if not g]
    rows = np.asarray([c.unknown.index(LENGTHS[j]) for j in soft], int)
    whiten = np.zeros((len(LENGTHS), len(LENGTHS)))
    # The marginal of the lengths: the weight, when unknown, is no residual.
    whiten[np.ix_(soft, soft)] = np.linalg.inv(np.linalg.cholesky(c.cov[np.ix_(rows, rows)]))
    log_mass = (
        log_known[..., known.index("weightkg")]
        if "weightkg" in known
        else mean[..., c.unknown.index("weightkg")]
    )
    return given, target, whiten, log_mass


def scale_to(
    body: Body | None,
    measurements: dict[str, float],
    *,
    sex: str | None = None,
    prior: PopulationPrior | None = None,
) -> Body:
    """The body scaled to the given measurements (module docstring).

    Args:
        body: the template whose proportions fill in what nothing decides; None: the embedded
            median body of `sex`.
        measurements: {name: value} in metres (`weightkg` in kg); names from
            `diffbody.MEASUREMENT_NAMES` (ANSUR II's).
        sex: "male" or "female": picks the default prior and template.
        prior: a `PopulationPrior` (default: every ANSUR II subject of `sex`).

    Returns:
        A new `Body`: the given measurements reproduced (to 1e-5 relative), the others at
        their population mean given those, masses summing to the given weight (or its
        conditional median).

    Raises:
        KeyError: an unknown measurement name (the message lists the valid ones).
        ValueError: a value that is not a positive number, a length over 10 m, a value more
            than 6 standard deviations from its mean given the other given values, or a
            combination the body's proportions cannot reproduce within 1 mm.
    """
    prior = _prior(prior, sex)
    template = _template(body, prior.sex)
    given = _check_values(measurements)
    outliers = prior.outliers(given, MAX_SD)
    if outliers:
        raise ValueError("scale_to: " + "; ".join(outliers))
    known = tuple(given)
    log_known = np.log([given[n] for n in known])
    mask, target, whiten, log_mass = _conditioned(prior, known, log_known)
    log_scales, _, _ = _solve_people(template, mask, target, whiten, 1)
    out = _finish(template, log_scales[0], float(np.exp(log_mass)))
    _check_reproduced(out, given)
    return out


def _finish(template: Body, log_scales: ArrayLike, mass: float) -> Body:
    """The scaled body, named as such."""
    body = scaled_body(template, log_scales, jnp.asarray(mass, template.lengths.dtype))
    return dataclasses.replace(body, name=f"{template.name}-scaled", source="diffbody.scale_to")


def _check_reproduced(body: Body, given: dict[str, float]) -> None:
    if not given:
        return
    got = np.asarray(measure(body, tuple(given)))
    bad = [
        f"{n} {got[i]:.4f} instead of {v:.4f}"
        for i, (n, v) in enumerate(given.items())
        if abs(got[i] - v) > (1e-3 if UNITS[n] == "m" else 1e-2)
    ]
    if bad:
        raise ValueError(
            "scale_to: the body's proportions cannot reproduce these together (some "
            f"measurements share a landmark, see diffbody.MEASUREMENTS): {'; '.join(bad)}"
        )


def scale_to_percentile(sex: str, percentile: float | int, *, body: Body | None = None) -> Body:
    """The body of `sex` with every measurement at `percentile` (0-100) of that sex's ANSUR II
    distribution: stature and weight exactly, the other lengths as close as the body's
    proportions allow (least squares, whitened by the population's covariance given stature
    and weight), as the embedded median bodies were built."""
    check_sex(sex)
    if not 0 < float(percentile) < 100:
        raise ValueError(f"percentile must lie in (0, 100), got {percentile!r}")
    prior = _default_prior(sex)
    _, values = ansur2_subjects(sex)
    at = dict(zip(MEASUREMENT_NAMES, np.percentile(values, percentile, axis=0)))
    template = _template(body, sex)
    known = ("stature", "weightkg")
    log_known = np.log([at[n] for n in known])
    mask, _, whiten, _ = _conditioned(prior, known, log_known)
    target = np.log([at[n] for n in LENGTHS])
    log_scales, _, _ = _solve_people(template, mask, target, whiten, 1)
    out = _finish(template, log_scales[0], at["weightkg"])
    return dataclasses.replace(out, name=f"{sex}{percentile:g}")


@dataclasses.dataclass(frozen=True)
class PopulationScaling:
    """Many bodies scaled at once (`scale_population`): per subject the group scale
    factors, the total mass, every measurement of the scaled body, and whether the given
    measurements were reproduced within 1 mm (0.01 kg)."""

    template: Body
    given: tuple[str, ...]
    log_scales: np.ndarray  # (n, 2, n_group): axial, radial
    masses: np.ndarray  # (n,) kg
    measurements: np.ndarray  # (n, len(MEASUREMENT_NAMES)), m and kg
    reproduced: np.ndarray  # (n,) bool
    converged: np.ndarray  # (n,) bool: optimistix's solve met its tolerance

    def body(self, i: int) -> Body:
        """Subject i's scaled body."""
        return _finish(self.template, jnp.asarray(self.log_scales[i]), float(self.masses[i]))


def scale_population(
    known: tuple[str, ...],
    values: np.ndarray,
    *,
    sex: str | None = None,
    prior: PopulationPrior | None = None,
    body: Body | None = None,
    chunk_size: int = 1024,
    progress: bool = True,
    out: str | os.PathLike | None = None,
    resume: bool = False,
) -> PopulationScaling:
    """`scale_to` for many people with the same known measurements, in one vmapped,
    compiled solve per chunk of rows (the last chunk padded), with a progress bar.

    Args:
        known: the names of the given measurements (columns of `values`).
        values: (n, len(known)) in metres (weightkg in kg).
        sex, prior, body: as for `scale_to`.
        chunk_size: rows per compiled call.
        progress: print a progress bar to stderr.
        out: a folder that keeps every finished chunk as it is done; an interrupt raises
            `Interrupted` (a KeyboardInterrupt) saying how many people it holds, and
            `resume=True` reads those and scales the rest (refused, naming what changed,
            for other values or settings).

    Rows are not refused for being far from the population: `reproduced` says which were
    matched. A row with a value that is not finite and > 0 is not solved (converged and
    reproduced False).
    """
    prior = _prior(prior, sex)
    template = _template(body, prior.sex)
    known = check_names(known)
    values = np.asarray(values, float)
    if values.ndim != 2 or values.shape[1] != len(known):
        raise ValueError(f"values must be (n, {len(known)}), got shape {values.shape}")
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
    valid = np.all(np.isfinite(values) & (values > 0), axis=1)
    log_known = np.log(np.where(valid[:, None], values, 1.0))
    mask, target, whiten, log_mass = _conditioned(prior, known, log_known)
    mass = np.where(valid, np.exp(log_mass), np.nan)
    store = None
    if out is not None:
        settings = {"function": "scale_population", "known": " ".join(known)}
        prior_hash = input_hash(np.asarray(prior.mean), np.asarray(prior.cov))
        settings |= {"values": input_hash(values), "prior": f"{prior.sex} {prior_hash}"}
        settings |= dict(body_fields(template)) | {"float": "float64"}  # solved in float64
        chunk = min(chunk_size, len(values))
        store = ChunkStore.open(out, settings, chunk, resume)
    log_scales, converged, lengths = _solve_people(
        template, mask, target, whiten, chunk_size, progress, store
    )
    measured = np.stack(
        [mass if n == "weightkg" else lengths[:, LENGTHS.index(n)] for n in MEASUREMENT_NAMES], 1
    )
    tol = np.asarray([1e-3 if UNITS[k] == "m" else 1e-2 for k in known])
    cols = [MEASUREMENT_NAMES.index(k) for k in known]
    reproduced = valid & np.all(np.abs(measured[:, cols] - values) <= tol, axis=1)
    return PopulationScaling(
        template, known, log_scales, mass, measured, reproduced, valid & converged
    )
