"""What touches what in a pose (docs/design.md, section 10): `contact_report`."""

from dataclasses import dataclass

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._body import Body, Pose
from .._kinematics import forward
from ._distances import closest_pair_gaps, environment_gaps
from ._environment import Environment
from ._pairs import sphere_pairs

# Surfaces closer than this touch (m).
TOUCH = 1e-4


@dataclass(frozen=True)
class Contact:
    """One touching or interpenetrating pair: two segments, or a segment and a shape.

    sphere_a, sphere_b: the sphere pair `Target.no_contact` measures, the one deepest
    beyond its rest overlap (the closest sphere for a shape);
    depth: how far they interpenetrate (m; 0 when they just touch or are apart);
    rest_depth: their interpenetration in the standard position (m; 0 for a shape);
    excess: depth - rest_depth, what `Target.no_contact` keeps <= -margin."""

    a: str
    b: str
    sphere_a: int
    sphere_b: int  # -1 for a shape
    depth: float
    rest_depth: float

    @property
    def excess(self) -> float:
        return self.depth - self.rest_depth


@dataclass(frozen=True)
class ContactReport:
    """The pairs that touch or interpenetrate in a pose, deepest first (`contact_report`)."""

    contacts: tuple[Contact, ...]

    def deeper_than_rest(self, tol: float = 1e-3) -> tuple[Contact, ...]:
        """The contacts deeper than at rest by more than `tol` (m)."""
        return tuple(c for c in self.contacts if c.excess > tol)

    def __str__(self) -> str:
        if not self.contacts:
            return "no contact"
        lines = [f"{'pair':<34} {'depth mm':>9} {'at rest':>8} {'beyond':>7}"]
        for c in self.contacts:
            lines.append(
                f"{c.a + ' - ' + c.b:<34} {1e3 * c.depth:>9.1f} {1e3 * c.rest_depth:>8.1f}"
                f" {1e3 * c.excess:>7.1f}"
            )
        return "\n".join(lines)


def _self_gaps(body, pose, i, j, allowance, group, n_groups):
    """Per group: the closest distance, and the gap and index of the pair deepest beyond its
    allowance (what `Target.no_contact` measures)."""
    k = forward(body, pose)
    c, r = k.sphere_centers, k.sphere_radii
    raw, _ = closest_pair_gaps(c, r, i, j, jnp.zeros_like(allowance), group, n_groups)
    gap, deepest = closest_pair_gaps(c, r, i, j, allowance, group, n_groups)
    return raw, gap, deepest


def _env_gaps(body, pose, env, segment, n):
    k = forward(body, pose)
    return environment_gaps(k.sphere_centers, k.sphere_radii, env, segment, n)


_self_gaps_jit = eqx.filter_jit(_self_gaps)
_env_gaps_jit = eqx.filter_jit(_env_gaps)


def contact_report(
    body: Body, pose: Pose, environment: Environment | None = None, tol: float = TOUCH
) -> ContactReport:
    """The segment pairs (those `Target.no_contact` checks, diffbody.contact._pairs) and
    segment-shape pairs whose closest spheres are within `tol` (m) of touching, or
    interpenetrate, with the depth of the sphere pair `Target.no_contact` measures against
    its depth in the standard position. Host side."""
    pairs = sphere_pairs(body)
    names = body.segment_names
    allowance = pairs.allowance
    closest, gaps, k = _self_gaps_jit(
        body,
        pose,
        jnp.asarray(pairs.i),
        jnp.asarray(pairs.j),
        jnp.asarray(allowance),
        pairs.segment_pair,
        len(pairs.segments),
    )
    closest, gaps, k = np.asarray(closest), np.asarray(gaps), np.asarray(k)
    out = []
    for row, (a, b) in enumerate(pairs.segments):
        if closest[row] <= tol:
            p = k[row]
            depth = max(-(float(gaps[row]) + float(allowance[p])), 0.0)
            rest = max(-float(pairs.rest[p]), 0.0)
            out.append(Contact(names[a], names[b], int(pairs.i[p]), int(pairs.j[p]), depth, rest))
    if environment is not None and environment.n_shapes:
        seg = np.asarray(body.sphere_segment, int)
        gaps, k = _env_gaps_jit(body, pose, environment, seg, body.n_segments)
        gaps, k = np.asarray(gaps), np.asarray(k)
        shapes = environment.shape_names()
        for s in sorted(set(seg.tolist())):
            for c, shape in enumerate(shapes):
                if gaps[s, c] <= tol:
                    out.append(
                        Contact(
                            names[s], shape, int(k[s, c]), -1, max(-float(gaps[s, c]), 0.0), 0.0
                        )
                    )
    return ContactReport(tuple(sorted(out, key=lambda c: -c.excess)))
