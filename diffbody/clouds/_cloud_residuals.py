"""The residuals of a sphere-cloud fit (docs/design.md, section 7): its unknowns
(`FitLayout`: the pose as the reach core's free vector of the whole tree, the log axial and
radial factors of the scale groups), the model spheres they place ((n_sph, 4): centre and
radius, m), the correspondences of a stage and its residual rows.

A stage's correspondences (`pairs_at`): each measured sphere is its matched model sphere when
they are known, else a soft one-to-one assignment at temperature T (`softassign`), each pair
weighted by Geman-McClure at loss scale c. The staged fit that anneals T and c: `_cloud_fit`.
"""

from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._body import Body, Pose
from ..anthropometry._scaling import N_GROUPS, log_scaled
from ..problem._points import tree_points
from ..problem._problem import Problem, make_problem
from ..problem._unknowns import Layout, whole_tree_layout

FIT_NAMES = ("pose", "lengths", "radii")
SINKHORN = 30  # rounds of normalisation of one soft assignment
C_MEDIAN = 3.0  # the outlier scale is at least this many median residual distances


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


def model_spheres(start: Start, lay: FitLayout, z: Array) -> Float[Array, "n_sph 4"]:
    """World centres and radii (m) of the model's spheres for the unknowns z: the point
    kernel (one walk, closed-form derivatives) on the template's problem with the scaled
    lengths and sphere origins."""
    x, log_axial, log_radial = lay.split(z, start)
    body = log_scaled(start.problem.body, log_axial, log_radial)
    chain = lay.pose.chain
    slots = tuple(chain.position(int(s)) for s in body.sphere_segment)
    origins = body.sphere_origins
    centers = tree_points(slots, start.problem, body.lengths, origins, origins[:, 2], x)
    return jnp.concatenate([centers, body.sphere_radii[:, None]], axis=-1)


def pack(lay: FitLayout, start: Start) -> Array:
    parts = (start.x, start.log_axial, start.log_radial)
    return jnp.concatenate([p for p, n in zip(parts, lay.sizes) if n])


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
