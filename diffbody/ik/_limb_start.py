"""The closed-form limb start (docs/design.md, section 6): a limb reaching for one point
target, posed in closed form before the solver polishes it.

A limb is a ball joint (shoulder, hip: the upper segment, both swing components free) and a
hinge below it (elbow, knee: the hinge segment, its flexion free), the effector on or below
the hinge. Everything else stays as in the start: the chain above the ball joint, the hinge
segment's twist and the segments below it (so the hinge-to-effector vector is rigid in the
hinge's frame).

1. The flexion from the ball-to-target distance (law of cosines): turning the hinge by
   delta about its axis a moves the effector to E + Rot(a, delta) r (E the hinge joint, r
   the effector from it), at a distance from the ball joint S of
   |e + Rot(a, delta) r|^2 = |e|^2 + |r|^2 + 2 (C + A cos delta + B sin delta), with
   e = E - S, C = e . r_par, A = e . r_perp, B = e . (a x r). Of the two roots the one
   within the hinge's range is kept (an elbow or knee flexes one way: it never flips); a
   distance out of the limb's span takes the nearest extreme.
2. The swivel (the limb's plane about the ball-to-target line) from the start: the whole
   limb below the ball joint turns by the smallest rotation taking the ball-to-effector
   line onto the ball-to-target line.
3. The upper segment's new frame as a swing vector in its socket (its socket frame is
   `R_socket_rest @ exp_swing(w)`, with the table twist of `socket_frames_from_swing`) and
   a twist (the rest of the rotation about its own axis), each put within its limits (box,
   cone, twist range) and turned into free variables by the bounded maps (`unsquash`).

Where the closed form does not apply (a center-of-gravity target, a re-rooted body, an axis
target on the limb, several point targets on one limb, a limb whose joints are not free),
that limb keeps the start's posture.
"""

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import Body
from .._device_arrays import take
from .._kinematics import feature_points, socket_frames_from_swing
from .._rotations import exp_rotvec, safe_norm, swing_rotation
from ..problem._problem import Problem
from ..problem._targets import TargetSet
from ..problem._unknowns import Layout, into_cone, point_segment, squash, unsquash


@dataclass(frozen=True)
class Limb:
    """One limb posed in closed form (static): its target row, effector and segments, and
    where its free variables sit in the free vector (-1: not free)."""

    row: int  # the point target's row
    effector: int  # into [joints, features]
    upper: int  # the ball joint's segment (upper arm, thigh)
    hinge: int  # the hinge's segment (forearm, shank)
    x_upper: tuple[int, int, int]  # free-vector entries of the upper swing_x, swing_y, twist
    x_hinge: int  # free-vector entry of the hinge's flexion (its swing_y)


def limbs(body: Body, layout: Layout, axis_segments: tuple[int, ...]) -> tuple[Limb, ...]:
    """The limbs of a layout that take the closed-form start (static, host: run when a
    solve is traced). `axis_segments`: the segments of the axis targets."""
    if layout.full:
        return ()
    seg = layout.chain.segments
    pos = {s: k for k, s in enumerate(seg)}
    n_sx, n_sy = len(layout.swing_x), len(layout.swing_y)

    def entry(part: tuple[int, ...], s: int, offset: int) -> int:
        return offset + part.index(pos[s]) if s in pos and pos[s] in part else -1

    found = []
    for row, index in enumerate(layout.points):
        if index >= body.n_joints + len(body.feature_names) or index == 0:
            continue
        for hinge in body.path_to_top(point_segment(body, index)):
            upper = int(body.parent[hinge])
            if body.limit_kind[hinge] != "hinge" or body.standard_kind[hinge] != "swing":
                continue
            x_hinge = entry(layout.swing_y, hinge, n_sx)
            x_upper = (
                entry(layout.swing_x, upper, 0),
                entry(layout.swing_y, upper, n_sx),
                entry(layout.twist, upper, n_sx + n_sy),
            )
            if upper >= 0 and x_hinge >= 0 and min(x_upper[:2]) >= 0:
                found.append(Limb(row, index, upper, hinge, x_upper, x_hinge))
            break
    uppers = [limb.upper for limb in found]
    on_limb = {s for a in axis_segments for s in body.path_to_top(a)}
    return tuple(
        limb for limb in found if uppers.count(limb.upper) == 1 and limb.upper not in on_limb
    )


def limb_start(
    body: Body, layout: Layout, targets: TargetSet, problem: Problem
) -> Float[Array, " n_free"]:
    """The free vector of the closed-form start: `problem.x0` (the problem's start) with every
    limb of `limbs` posed toward its point target (one whose weight is zero keeps the start).
    Not differentiated (a start)."""
    if problem.plan is not None:
        return _planned_limb_start(body, targets, problem)
    found = limbs(body, layout, targets.axis_segment)
    x = problem.x0
    if not found:
        return x
    links, tau = problem.start, problem.tau_start
    for limb in found:
        w_hinge = problem.swing0[layout.chain.position(limb.hinge)]
        target = targets.point_xyz[limb.row]
        w, twist, flexion = _pose_limb(
            body, links, tau, w_hinge, limb.upper, limb.hinge, limb.effector, target
        )
        entries = list(limb.x_upper[:2]) + [limb.x_hinge]
        values = [w[0], w[1], flexion]
        if limb.x_upper[2] >= 0:
            entries.append(limb.x_upper[2])
            values.append(twist)
        k = np.asarray(entries)
        u = unsquash(jnp.stack(values), problem.lo[k], problem.hi[k])
        use = targets.point_weight[limb.row] > 0
        x = x.at[k].set(jnp.where(use, u, x[k]))
    return x


def _planned_limb_start(body: Body, targets: TargetSet, problem: Problem) -> Array:
    """`limb_start` on the whole tree's problem: its plan's limbs (data), all at once."""
    plan, links, tau = problem.plan, problem.start, problem.tau_start
    position = problem.slot_of()  # each segment's chain slot

    def one(row, effector, upper, hinge):
        w_hinge = problem.swing0[take(position, hinge)]
        target = targets.point_xyz[row]
        w, twist, flexion = _pose_limb(body, links, tau, w_hinge, upper, hinge, effector, target)
        return jnp.stack([w[0], w[1], flexion, twist])

    values = jax.vmap(one)(plan.limb_row, plan.limb_effector, plan.limb_upper, plan.limb_hinge)
    k = plan.limb_entries  # (L, 4): upper swing_x, swing_y, hinge flexion, upper twist
    safe = jnp.maximum(k, 0)
    u = unsquash(values, problem.lo[safe], problem.hi[safe])
    use = plan.limb_use & (targets.point_weight[plan.limb_row] > 0)
    n = problem.x0.shape[0]
    at = jnp.where(use[:, None] & (k >= 0), k, n)  # n: dropped
    return problem.x0.at[at.ravel()].set(u.ravel(), mode="drop")


def _pose_limb(body: Body, links, tau: Array, w_hinge: Array, upper, hinge, effector, target):
    """The upper segment's swing vector (2,) and twist, and the hinge's flexion (its
    swing_y), that put the effector at `target` (as near as the limits allow); `w_hinge`:
    the hinge's swing vector in the start. The segments and the effector (into [joints,
    features]) are ints, or traced (the whole tree's plan)."""
    S = links.p_proximal[upper]
    E = links.p_proximal[hinge]
    P = _effector(body, links, tau, effector)
    # 1. The flexion: |e + Rot(a, delta) r| = |target - S|.
    a = links.R_base[hinge][:, 1]
    e, r = E - S, P - E
    r_par = jnp.dot(a, r) * a
    A = jnp.dot(e, r - r_par)
    B = jnp.dot(e, jnp.cross(a, r))
    C = jnp.dot(e, r_par)
    d2 = jnp.sum((target - S) ** 2)
    K = 0.5 * (d2 - jnp.dot(e, e) - jnp.dot(r, r)) - C
    rho = jnp.sqrt(A * A + B * B)
    phi = jnp.arctan2(B, A)
    alpha = jnp.arccos(jnp.clip(K / jnp.where(rho > 0, rho, 1.0), -1.0, 1.0))
    lo, hi = _representable(body.swing_lo[hinge, 1], body.swing_hi[hinge, 1])
    roots = jnp.stack([phi + alpha, phi - alpha])
    deltas = jnp.arctan2(jnp.sin(roots), jnp.cos(roots))
    flexions = w_hinge[1] + deltas
    pick = jnp.argmin(_outside(flexions, lo, hi) + 1e-3 * jnp.abs(deltas))
    flexion = jnp.clip(flexions[pick], lo, hi)
    delta = flexion - w_hinge[1]
    # 2. The swivel: the limb turns about S onto the ball-to-target line, then about that
    # line by the first of SWIVELS (0 first: the start's plane) that the limits admit.
    c, s = jnp.cos(delta), jnp.sin(delta)
    r_new = r_par + c * (r - r_par) + s * jnp.cross(a, r)
    line = _unit(target - S)
    R_turn = swing_rotation(_unit(E + r_new - S), line)
    psi = jnp.asarray(SWIVELS, S.dtype)
    Q = exp_rotvec(psi[:, None] * line) @ (R_turn @ links.R_twisted[upper])
    # 3. The frames in their socket as swing vectors and twists.
    parent = take(np.asarray(body.parent, int), upper)
    R_socket = links.R_twisted[parent] @ body.R_parent_socket[upper]
    L = R_socket.T @ Q
    d = jnp.einsum("ji,kj->ki", body.R_socket_rest[upper], L[:, :, 2])
    w = jax.vmap(_swing_of_direction)(d)
    k = len(SWIVELS)
    B_w = socket_frames_from_swing(body, w, _repeated(upper, k))
    M = jnp.einsum("kji,kjl->kil", B_w, L)
    twist = jnp.arctan2(M[:, 1, 0], M[:, 0, 0])
    # The first swivel within the limits, else the one least outside them.
    w_lo, w_hi = _representable(body.swing_lo[upper], body.swing_hi[upper])
    t_lo, t_hi = _representable(body.twist_lo[upper], body.twist_hi[upper])
    cone = jnp.maximum(safe_norm(w) - body.swing_max[upper], 0.0)
    outside = jnp.sum(_outside(w, w_lo, w_hi), -1) + cone + _outside(twist, t_lo, t_hi)
    pick = jnp.argmin(outside + 1e-3 * jnp.abs(psi))
    w = into_cone(jnp.clip(w[pick], w_lo, w_hi)[None], body.swing_max[upper][None])[0]
    return w, jnp.clip(twist[pick], t_lo, t_hi), flexion


# Turns of the limb about the ball-to-target line tried in order of preference (rad): the
# start's own plane first, then ever farther from it on either side.
SWIVELS = tuple(
    float(a)
    for a in np.pi / 8 * np.asarray([0, 1, -1, 2, -2, 3, -3, 4, -4, 5, -5, 6, -6, 7, -7, 8])
)


def _representable(lo: Array, hi: Array) -> tuple[Array, Array]:
    """The range [lo, hi] as far as the bounded maps' start values reach (`unsquash` keeps
    a start off the bounds)."""
    return squash(unsquash(lo, lo, hi), lo, hi), squash(unsquash(hi, lo, hi), lo, hi)


def _outside(v: Array, lo: Array, hi: Array) -> Array:
    """How far v lies outside [lo, hi] (0 inside)."""
    return jnp.maximum(lo - v, 0.0) + jnp.maximum(v - hi, 0.0)


def _repeated(index, k: int):
    """(k,) copies of an index, host or traced."""
    return jnp.full(k, index) if isinstance(index, jax.Array) else np.full(k, index)


def _effector(body: Body, links, tau: Array, index) -> Array:
    """The start's world position of a joint or feature effector (`index` into [joints,
    features]; an int, or traced: then both are placed and the effector's kept)."""
    n_j, n_f = body.n_joints, len(body.feature_names)
    if not isinstance(index, jax.Array):
        if index < n_j:
            return links.p_distal[index - 1]
        seg = int(point_segment(body, index))
        return _feature(body, links, tau, np.asarray([index - n_j]), seg)
    joint = links.p_distal[jnp.clip(index - 1, 0, body.n_segments - 1)]
    if not n_f:
        return joint
    f = jnp.clip(index - n_j, 0, n_f - 1)
    sph = take(np.asarray(body.feature_sphere, int), f)
    seg = take(np.asarray(body.sphere_segment, int), sph)
    return jnp.where(index < n_j, joint, _feature(body, links, tau, f[None], seg))


def _feature(body: Body, links, tau: Array, f, seg) -> Array:
    """The start's world position of feature f (1,) on segment seg."""
    p, _ = feature_points(
        body, f, links.R_base[seg][None], links.p_proximal[seg][None], tau[seg][None]
    )
    return p[0]


def _swing_of_direction(d: Float[Array, "3"]) -> Float[Array, "2"]:
    """The swing vector taking the rest direction +Z to the unit direction d (rest frame):
    angle atan2(|d_xy|, d_z) about the axis z x d."""
    rho = safe_norm(d[:2])
    small = rho < 1e-9
    k = jnp.where(small, 1.0, jnp.arctan2(rho, d[2]) / jnp.where(small, 1.0, rho))
    return jnp.stack([-d[1] * k, d[0] * k])


def _unit(v: Array) -> Array:
    n = safe_norm(v)
    return v / jnp.where(n > 0, n, 1.0)
