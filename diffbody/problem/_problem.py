"""One reach problem: (chain, unknowns, start) -> weighted residuals, one walk per
evaluation (docs/design.md, section 6).

Everything that does not change during a solve (the start's frames above the first
unknown, the bounds, the pull toward the start) is computed once, when the problem is built;
`residuals` then maps the free vector to swing vectors and twists of the live segments,
walks them once (`walk_links`) and compares the effectors with the targets.
"""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import Body, Pose
from .._kinematics import (
    Links,
    full_chain,
    pose_frames,
    reroot,
    walk_links,
    world_base,
)
from .._limits import angles_from_swing, swing_vector
from .._posture import angles_of_rotation
from .._rotations import exp_rotvec, rot_z, safe_norm
from .._spine import spine_angles
from ._constraints import WEIGHT, constraint_rows
from ._points import socket_state
from ._targets import TargetSet
from ._terms import cog_term, place, sphere_term, target_terms
from ._tree import Plan
from ._unknowns import Layout, into_cone, squash, unsquash

# The pull toward the start, per unit of the free variables: it settles the redundant
# directions of a chain without moving reached targets by more than micrometres. The
# spine's pull is stronger, so once it may move it bends only as far as the arm needs.
PULL = 1e-6
SPINE_PULL = 3e-5
# The spine's free variables are its bounded variables times this factor, so that a unit of
# the solver's step bends the spine a quarter as far: Levenberg-Marquardt's damped steps
# are shortest in the free variables, so the arm takes most of a reach and the trunk bends
# progressively, only as far as the arm needs (the reach ladder, README "Reach").
SPINE_STIFFNESS = 2.0
# Standing, the pelvis's shift and the knees and ankles are this much stiffer (`stiffness_of`).
STANDING_STIFFNESS = 4.0


def _gather_or(values: Array, index: np.ndarray, mask: np.ndarray, default: Array) -> Array:
    """Row k of the result is values[index[k]] where mask[k], else default[k] (no scatter)."""
    if values.shape[0] == 0:
        return default
    return jnp.where(mask, values[np.where(mask, index, 0)], default)


class Rows(NamedTuple):
    """A problem's weighted residual rows, by term (`Problem.rows`)."""

    points: Array  # (3 n_p,)
    axes: Array  # (3 n_a,)
    constraints: Array  # (c,)
    pull: Array  # (n_free,)


class Problem(eqx.Module):
    """Everything fixed during one solve. Build it with `make_problem`."""

    body: Body
    layout: Layout = eqx.field(static=True)
    swing0: Float[Array, "m 2"]  # rad, the start's swing vectors of the live segments
    tau0: Float[Array, " m"]  # rad, their twists
    R_socket0: Float[Array, "m 3 3"]  # the start's base frames in their sockets
    bases: Links  # the start's state of the segments the chain hangs from
    tau_bases: Float[Array, " n_base"]  # their twists
    position0: Float[Array, "3"]  # m, the start's root joint
    lo: Float[Array, " n_free"]  # bounds of the bounded unknowns (root: unused)
    hi: Float[Array, " n_free"]
    x0: Float[Array, " n_free"]  # the start's free variables
    pull: Float[Array, " n_free"]  # square roots of the pull weights
    stiffness: Float[Array, " n_free"]  # the free variables are the unknowns times this
    start: Links  # the start's links of every segment (global order), walked once
    tau_start: Float[Array, " n_seg"]  # the start's twists of every segment
    plan: Plan | None = None  # the whole tree's: what this solve moves and reaches (`_tree`)

    # --- the chain's segments (static, or the plan's on a limb chain) ---------------------
    def segments(self) -> np.ndarray | Array:
        """(m,) the global segment of each chain slot."""
        return chain_segments(self.layout, self.plan)

    def slot_of(self) -> np.ndarray | Array:
        """(n_seg,) each segment's slot (chain, then bases) where it is read."""
        if self.plan is not None and self.plan.slot_of is not None:
            return self.plan.slot_of
        return np.asarray(self.layout.read_slot, int)

    def slot_segments(self) -> np.ndarray | Array:
        """(m + n_bases,) the global segment of each slot (chain, then bases; the world 0)."""
        if self.plan is not None and self.plan.chain is not None:
            return jnp.concatenate([self.plan.chain, self.plan.base])
        lay = self.layout
        return np.maximum(np.asarray(lay.chain.segments + lay.bases, int), 0)

    # --- the free vector to the live segments -------------------------------------------
    def state(self, x: Array):
        """Swing vectors (m, 2), twists (m,), spine target (or None) and root placement of
        the free vector, every limit exact (box map, then the radial pull into the cone)."""
        lay, b = self.layout, self.body
        if self.plan is not None:
            x = jnp.where(self.plan.free, x, self.x0)
        sx, sy, tw, sp, root = lay.split(x / self.stiffness)
        lo_sx, lo_sy, lo_tw, lo_sp, _ = lay.split(self.lo)
        hi_sx, hi_sy, hi_tw, hi_sp, _ = lay.split(self.hi)
        m = lay.chain.size
        seg = self.segments()

        def spread(free: tuple[int, ...], values: Array, default: Array) -> Array:
            index = np.zeros(m, int)
            index[list(free)] = np.arange(len(free))
            mask = np.zeros(m, bool)
            mask[list(free)] = True
            return _gather_or(values, index, mask, default)

        w = jnp.stack(
            [
                spread(lay.swing_x, squash(sx, lo_sx, hi_sx), self.swing0[:, 0]),
                spread(lay.swing_y, squash(sy, lo_sy, hi_sy), self.swing0[:, 1]),
            ],
            axis=-1,
        )
        w = into_cone(w, b.swing_max[seg]) if m else w
        tau = spread(lay.twist, squash(tw, lo_tw, hi_tw), self.tau0)
        spine_target = squash(sp / SPINE_STIFFNESS, lo_sp, hi_sp) if lay.spine else None
        return w, tau, spine_target, root

    def links(self, x: Array) -> tuple[Links, Array]:
        """The live segments' links (chain order) and twists for the free vector: one walk."""
        lay, b = self.layout, self.body
        R, tau, position = socket_state(self, x)
        bases = self.bases
        if -1 in lay.bases:
            world = world_base(position)
            bases = jax.tree.map(
                lambda a, wb: jnp.where(_is_world(lay)[(...,) + (None,) * (a.ndim - 1)], wb, a),
                bases,
                world,
            )
        links = walk_links(b, lay.chain, R, tau, bases, self.segments())
        if lay.full:
            links = global_order(lay, links)
            links = reroot(b, links, position)
            links = _chain_order(lay, links)
        return links, tau

    # --- effectors and residuals ---------------------------------------------------------
    def placed(self, x: Array, targets: TargetSet) -> tuple[Array, Array, Array, Array | None]:
        """World positions of the point effectors (n_p, 3), the world directions of the
        axis targets' axes (n_a, 3), and what the constraints read: the centres of their
        spheres (k, 3) and the centre of gravity (3,) (None without balance). Each is a
        term of the one call of the point kernel (`_terms`)."""
        c = targets.constraints
        points, axes = target_terms(self, targets)
        terms = {("point", i): t for i, t in enumerate(points)} | {"axes": axes}
        if c is not None and c.spheres:
            terms["spheres"] = sphere_term(self, c.spheres)
        if c is not None and c.balance:
            terms["cog"] = cog_term(self)
        v = place(self, x, terms)
        empty = jnp.zeros((0, 3), x.dtype)
        p = [v[("point", i)] for i in range(len(points))]
        p = jnp.concatenate(p) if p else empty
        return p, v["axes"], v.get("spheres", empty), v.get("cog")

    def effectors(self, x: Array, targets: TargetSet) -> tuple[Array, Array]:
        """The point effectors (n_p, 3) and axis directions (n_a, 3) (`placed`)."""
        return self.placed(x, targets)[:2]

    def constraint_rows(self, x: Array, targets: TargetSet) -> tuple[Array, Array, Array, Array]:
        """The effectors, the constraints' unweighted rows and each kind's violation (m)."""
        p, axes, centers, cog = self.placed(x, targets)
        c = targets.constraints
        if c is None:
            return p, axes, jnp.zeros(0, x.dtype), jnp.zeros(0, x.dtype)
        radii = self.body.sphere_radii[np.asarray(c.spheres, int)]
        rows, worst = constraint_rows(c, centers, radii, cog)
        return p, axes, rows, worst

    def rows(self, x: Array, targets: TargetSet) -> "Rows":
        """The weighted residuals by term: points (m), axes (chord lengths ~ rad), the
        constraints (m, `WEIGHT` times), the pull toward the start."""
        p, axes, rows, _ = self.constraint_rows(x, targets)
        return Rows(
            points=(targets.point_weight[:, None] * (p - targets.point_xyz)).ravel(),
            axes=(targets.axis_weight[:, None] * (axes - targets.axis_direction)).ravel(),
            constraints=WEIGHT * rows,
            pull=self.pull * (x - self.x0),
        )

    def residuals(self, x: Array, targets: TargetSet) -> Array:
        """The weighted residuals (`rows`), one flat vector."""
        return jnp.concatenate(self.rows(x, targets))

    def errors(self, x: Array, targets: TargetSet) -> tuple[Array, Array, Array]:
        """Distances of the point targets (m), angles of the axis targets (rad) and each
        constraint kind's violation (m); finite for any finite target (no overflow of
        squares in float32)."""
        p, axes, _, worst = self.constraint_rows(x, targets)
        cos = jnp.clip(jnp.sum(axes * targets.axis_direction, axis=-1), -1.0, 1.0)
        return scaled_distance(p, targets.point_xyz), jnp.arccos(cos), worst

    # --- the public pose ----------------------------------------------------------------
    def pose(self, x: Array, init: Pose) -> Pose:
        """The public pose of the free vector: `init` with the live rows replaced (theta,
        phi, tau), the spine as its target when it moved."""
        lay, b = self.layout, self.body
        w, tau, spine_target, root = self.state(x)
        n = b.n_segments
        angles = jnp.asarray(init.angles)
        plan = self.plan
        if plan is not None and plan.chain is not None:
            # A limb chain: each moved segment reads its slot (a gather, no scatter).
            at = jnp.clip(plan.slot_of, 0, lay.chain.size - 1)
            W = jnp.where(plan.moves[:, None], w[at], swing_vector(b, angles))
            T = jnp.where(plan.moves, tau[at], angles[:, 2])
            angles = jnp.where(plan.moves[:, None], angles_from_swing(b, W, T), angles)
            return Pose(init.position, angles, init.spine_target)
        seg = np.asarray(lay.chain.segments, int)
        spine_rows = set(lay.spine)
        k = np.asarray([i for i in range(len(seg)) if i not in spine_rows and seg[i] != 0], int)
        if k.size:
            W = swing_vector(b, angles).at[seg[k]].set(w[k])
            T = angles[:, 2].at[seg[k]].set(tau[k])
            mask = np.zeros(n, bool)
            mask[seg[k]] = True
            if self.plan is not None:
                mask = mask & self.plan.moves
            angles = jnp.where(mask[:, None], angles_from_swing(b, W, T), angles)
        position = jnp.asarray(init.position)
        if lay.root:
            R0 = exp_rotvec(root[3:]) @ self.R_socket0[lay.chain.position(0)]
            placed = angles.at[0].set(angles_of_rotation(R0 @ rot_z(angles[0, 2])))
            # The whole tree's problem keeps a root it does not move as it is.
            angles = placed if self.plan is None else jnp.where(self.plan.free[-1], placed, angles)
            position = position + root[:3]
        if spine_target is None:
            spine_target = init.spine_target
        return Pose(position=position, angles=angles, spine_target=spine_target)


def scaled_distance(a: Array, b: Array) -> Array:
    """|a - b| along the last axis, computed as s |(a - b) / s| with s the largest
    component, so huge finite differences do not overflow."""
    d = a - b
    s = jnp.max(jnp.abs(d), axis=-1, keepdims=True)
    s = jnp.where(jnp.isfinite(s) & (s > 0), s, 1.0)
    return s[..., 0] * safe_norm(d / s)


def _is_world(lay: Layout) -> np.ndarray:
    return np.asarray([b == -1 for b in lay.bases])


def global_order(lay: Layout, links: Links) -> Links:
    order = np.argsort(np.asarray(lay.chain.segments))
    return jax.tree.map(lambda a: a[order], links)


def _chain_order(lay: Layout, links: Links) -> Links:
    return jax.tree.map(lambda a: a[np.asarray(lay.chain.segments)], links)


def start_links(body: Body, init: Pose) -> tuple[Links, Array, Array]:
    """The start's links of every segment (global order), its base frames in their
    sockets and its twists."""
    R_socket_base, tau = pose_frames(body, init)
    position = jnp.asarray(init.position, R_socket_base.dtype)
    chain = full_chain(body)
    seg = np.asarray(chain.segments)
    links = walk_links(body, chain, R_socket_base[seg], tau[seg], world_base(position))
    links = jax.tree.map(lambda a: a[np.argsort(seg)], links)
    return reroot(body, links, position), R_socket_base, tau


def make_problem(body: Body, layout: Layout, init: Pose, plan: Plan | None = None) -> Problem:
    """Build the fixed part of a solve (traceable: the init and the body may be traced);
    `plan`: the whole tree's (`_tree`), with `tree_layout`."""
    links, R_socket, tau = start_links(body, init)
    seg = chain_segments(layout, plan)
    bases_seg = np.asarray([max(s, 0) for s in layout.bases], int)
    if plan is not None and plan.base is not None:
        bases_seg = plan.base
    bases = jax.tree.map(lambda a: a[bases_seg], links)
    w_all = swing_vector(body, jnp.asarray(init.angles))
    sx, sy, tw = (np.asarray(a, int) for a in (layout.swing_x, layout.swing_y, layout.twist))
    lo_parts = [body.swing_lo[seg[sx], 0], body.swing_lo[seg[sy], 1], body.twist_lo[seg[tw]]]
    hi_parts = [body.swing_hi[seg[sx], 0], body.swing_hi[seg[sy], 1], body.twist_hi[seg[tw]]]
    x_parts = [w_all[seg[sx], 0], w_all[seg[sy], 1], tau[seg[tw]]]
    pull = [np.full(len(sx) + len(sy) + len(tw), np.sqrt(PULL))]
    if layout.spine:
        spine = body.spine
        total = (
            init.spine_target
            if init.spine_target is not None
            else spine_angles(body, spine, init).sum(0)
        )
        lo_parts.append(spine.lower.sum(0))
        hi_parts.append(spine.upper.sum(0))
        x_parts.append(jnp.asarray(total, w_all.dtype))
        pull.append(np.full(3, np.sqrt(SPINE_PULL)))
    lo, hi = jnp.concatenate(lo_parts), jnp.concatenate(hi_parts)
    x0 = unsquash(jnp.concatenate(x_parts), lo, hi)
    if layout.spine:
        x0 = x0.at[-3:].multiply(SPINE_STIFFNESS)
    if layout.root:
        zeros = jnp.zeros(6, x0.dtype)
        lo, hi, x0 = (jnp.concatenate([a, zeros]) for a in (lo, hi, x0))
        pull.append(np.full(6, np.sqrt(PULL)))
    stiffness = stiffness_of(body, layout) if plan is None else plan.stiffness
    x0 = x0 * stiffness
    return Problem(
        body=body,
        layout=layout,
        swing0=w_all[seg].reshape(-1, 2),
        tau0=tau[seg],
        R_socket0=R_socket[seg].reshape(-1, 3, 3),
        bases=bases,
        tau_bases=tau[bases_seg],
        position0=jnp.asarray(init.position, x0.dtype),
        lo=lo,
        hi=hi,
        x0=x0,
        pull=jnp.asarray(np.concatenate(pull), x0.dtype),
        stiffness=jnp.asarray(stiffness, x0.dtype),
        start=links,
        tau_start=tau,
        plan=plan,
    )


def chain_segments(layout: Layout, plan: Plan | None) -> np.ndarray | Array:
    """(m,) the global segment of each chain slot: the plan's on a limb chain (data), else
    the layout's."""
    if plan is not None and plan.chain is not None:
        return plan.chain
    return np.asarray(layout.chain.segments, int)


def stiffness_of(body: Body, layout: Layout) -> np.ndarray:
    """Per free variable, its stiffness (the spine's is in `state`): 1, but standing, the
    pelvis's shift and the knees and ankles `STANDING_STIFFNESS`, so that the damped steps
    bend the hips and the spine, as a person reaching does, rather than tilt the whole body
    over the ankles."""
    k = np.ones(layout.n_free)
    if not layout.standing:
        return k
    seg = np.asarray(layout.chain.segments, int)
    below_hips = body.below(body.thighs)  # the shanks and feet
    n_sx, n_sy, n_tw, n_sp, _ = layout.sizes
    parts = [layout.swing_x, layout.swing_y, layout.twist]
    at = 0
    for part in parts:
        for j, slot in enumerate(part):
            if seg[slot] in below_hips:
                k[at + j] = STANDING_STIFFNESS
        at += len(part)
    k[at + n_sp : at + n_sp + 3] = STANDING_STIFFNESS  # the root's shift
    return k
