"""The one point kernel (docs/design.md, section 6): world positions of points attached to
segments, for a problem's free vector, and their closed-form Jacobian.

Every residual of every fit is such a point: a joint, a feature, a marker with its offset,
a sphere centre, a centroid of the centre of gravity, or an axis (a difference of two
points). `tree_points` walks the problem's live chain once and places the points; its custom
JVP uses the walk's own output instead of autodiff's one tangent per unknown. An unknown
turning segment i at world rate w moves every point below i by w x (p - c_i), c_i the
segment's proximal joint, and a point on i itself by its share z / length of i's twist; the
rates come from the walk-free part of the posture (`socket_state`). So a Jacobian costs one
walk and a few small products. `jax.grad` and `jax.jacrev` of anything built on it work
through the JVP; derivatives with respect to the problem itself (a body under
differentiation) and re-rooted bodies fall back to plain autodiff through the walk.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, Float

from .._chain import on_paths
from .._device_arrays import take
from .._kinematics import (
    exp_swing,
    place_on_segments,
    socket_frames_from_swing,
    socket_rates_from_swing,
    spine_deviation,
    twist_fraction,
)
from .._rotations import exp_rotvec, matmul3
from ._unknowns import Layout


# --- the free vector as frames in their sockets (walk-free) ---------------------------------
def socket_state(problem, x: Array) -> tuple[Array, Array, Array]:
    """The free vector x of a `Problem` as every chain segment's base frame in its socket
    (m, 3, 3, chain order), its twist (m,) and the root joint's position (3,): what a walk
    composes. Each part below gives (chain rows, their frames, their twists or None: the
    state's); the last part naming a row wins (a gather, no scatter)."""
    lay = problem.layout
    w, tau, spine_target, root = problem.state(x)
    m = lay.chain.size
    parts = [(np.arange(m), problem.R_socket0, tau)]
    parts += swing_frames(problem, w) + spine_frames(problem, spine_target)
    parts += root_frame(problem, root)
    R = jnp.concatenate([f for _, f, _ in parts])[_last_of(m, [k for k, _, _ in parts])]
    twisted = [(k, t) for k, _, t in parts if t is not None]
    tau = jnp.concatenate([t for _, t in twisted])[_last_of(m, [k for k, _ in twisted])]
    position = problem.position0 + root[:3] if lay.root else problem.position0
    return R, tau, position


def swing_frames(problem, w: Array) -> list:
    """The frames of the segments with a free swing or twist."""
    lay = problem.layout
    k = np.asarray(sorted(set(lay.swing_x + lay.swing_y + lay.twist)), int)
    if not k.size:
        return []
    seg = problem.segments()[k]
    return [(k, socket_frames_from_swing(problem.body, w[k], seg), None)]


def spine_frames(problem, spine_target: Array | None) -> list:
    """The frames and twists of the vertebrae, bent to the spine target (Bendspine)."""
    lay, b = problem.layout, problem.body
    if not lay.spine:
        return []
    _, w_sp, tw_sp = spine_deviation(b, spine_target)
    k, r = np.asarray(lay.spine, int), np.asarray(lay.spine_rows, int)
    seg = np.asarray(lay.chain.segments, int)[k]
    R, tau = matmul3(b.R_socket_rest[seg], exp_swing(w_sp[r])), tw_sp[r]
    if problem.plan is not None:
        # The whole tree's problem: the vertebrae the solve does not bend stay as started.
        bent = problem.plan.vertebrae
        R = jnp.where(bent[:, None, None], R, problem.R_socket0[k])
        tau = jnp.where(bent, tau, problem.tau0[k])
    return [(k, R, tau)]


def root_frame(problem, root: Array) -> list:
    """The whole body's frame, turned by the root's rotation vector about the root joint."""
    lay = problem.layout
    if not lay.root:
        return []
    k0 = np.asarray([lay.chain.position(0)])
    return [(k0, matmul3(exp_rotvec(root[3:])[None], problem.R_socket0[k0]), None)]


def _last_of(m: int, rows: list[np.ndarray]) -> np.ndarray:
    """(m,) for each of m rows, its place in the concatenation of parts whose rows are
    `rows`: the last part naming a row wins."""
    pick, offset = np.zeros(m, int), 0
    for r in rows:
        pick[r] = offset + np.arange(len(r))
        offset += len(r)
    return pick


# --- the points -------------------------------------------------------------------------------
def walk_points(problem, slots, lengths, offsets, heights, x):
    """World points (k, 3) at `offsets` (k, 3; their segments' cross of axes) on the chain
    or base slots `slots` (k,; data), each turned by the share heights / length of its
    segment's twist, on the problem's body with segment `lengths` (n_seg,); also the walk's
    links and twists (chain order). One walk (`Problem.links`)."""
    slots = as_slots(slots)
    body = eqx.tree_at(lambda b: b.lengths, problem.body, lengths)
    links, tau = eqx.tree_at(lambda p: p.body, problem, body).links(x)
    allof = jax.tree.map(lambda c, s: jnp.concatenate([c, s]), links, problem.bases)
    tau_all = jnp.concatenate([tau, problem.tau_bases])
    seg = take(problem.slot_segments(), slots)
    local = place_on_segments(body, seg, offsets, heights, allof.R_base[slots], tau_all[slots])
    return allof.p_proximal[slots] + local, links, tau


def as_slots(slots) -> np.ndarray | Array:
    """Slots as an int array (a tuple on the host becomes a NumPy array)."""
    return slots if isinstance(slots, jax.Array) else np.asarray(slots, np.int32)


def _ancestry(lay: Layout, slots) -> tuple[np.ndarray | Array, np.ndarray | Array]:
    """(k, m) masks over the chain: chain segment i on point k's path to the top (itself
    included), and i being point k's own segment; zero rows for points on bases."""
    m = lay.chain.size
    every = range(m + lay.chain.n_bases)
    on_path = on_paths(lay.chain.parent_slot, every)
    own = on_paths([-1] * m, every)
    return take(on_path, slots), take(own, slots)


def _closed_form(problem) -> bool:
    """Whether the kernel has its closed-form derivatives: the body hangs from its default
    root (a re-rooted body's whole tree moves with every joint: autodiff)."""
    b = problem.body
    return not problem.layout.full or b.root_joint == b.default_root_joint


def tree_points(
    slots,
    problem,
    lengths: Float[Array, " n_seg"],
    offsets: Float[Array, "k 3"],
    heights: Float[Array, " k"],
    x: Float[Array, " n_free"],
) -> Float[Array, "k 3"]:
    """World positions (m) of points at `offsets` on the segments of the problem's chain or
    base `slots` (k ints: a tuple, or an array that may be data), turned by the share
    heights / length of their segment's twist, for the free vector x of a `Problem` whose
    body has segment `lengths`: one walk, with closed-form derivatives (module
    docstring)."""
    return _tree_points(as_slots(slots), problem, lengths, offsets, heights, x)


@jax.custom_jvp
def _tree_points(slots, problem, lengths, offsets, heights, x):
    return walk_points(problem, slots, lengths, offsets, heights, x)[0]


def _zero(t) -> bool:
    return isinstance(t, SymbolicZero)


def _vee(M: Array) -> Array:
    """The vector of the skew part of matrices (..., 3, 3)."""
    return 0.5 * jnp.stack(
        [M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]],
        axis=-1,
    )


def _spread(m: int, k: np.ndarray, values: Array) -> Array:
    """(..., len(k), d) values of chain rows k -> (..., m, d), zero elsewhere (a gather)."""
    index = np.zeros(m, int)
    index[k] = 1 + np.arange(len(k))
    return jnp.concatenate([jnp.zeros_like(values[..., :1, :]), values], axis=-2)[..., index, :]


def _part_rates(problem, part, value: Array, units: np.ndarray) -> tuple[Array, Array]:
    """Body rates (u, m, 3), vee(R^T dR) of the base frames in their sockets, and twist
    rates (u, m) of the frames a part of the state makes (`socket_state`), per unit
    tangent of that part (u, ...)."""
    m = problem.layout.chain.size

    def one(d):
        out, d_out = jax.jvp(lambda v: part(problem, v), (value,), (d,))
        rate = jnp.zeros((m, 3), value.dtype)
        twist = jnp.zeros((m, 1), value.dtype)
        for (k, R, t), (_, dR, dt) in zip(out, d_out):
            rate = rate + _spread(m, k, _vee(matmul3(jnp.swapaxes(R, -1, -2), dR)))
            twist = twist if t is None else twist + _spread(m, k, dt[:, None])
        return rate, twist[:, 0]

    return jax.vmap(one)(jnp.asarray(units, value.dtype))


def _unit_rates(problem, x: Array) -> tuple[Array, Array, Array]:
    """Per unit tangent of the problem's state, every chain segment's body rate (g, m, 3),
    twist rate (g, m) and the root joint's shift (g, 3), for the unit tangents of the
    swing vectors' w_x and w_y (all segments at once), the twists, the spine target's 3
    and the root's 6 components. Each part of the state moves only its own segments'
    frames, and each frame only by its own entries (the Jacobian is block-diagonal), so
    these few derivative passes give every rate, where autodiff would carry one tangent per
    unknown through every part."""
    lay = problem.layout
    w, tau, spine, root = problem.state(x)
    m, dtype = lay.chain.size, tau.dtype
    rates, twists = [], []
    # The swings in closed form (each row's own w moves only its own frame).
    k = np.asarray(sorted(set(lay.swing_x + lay.swing_y + lay.twist)), int)
    r = jnp.zeros((2, m, 3), dtype)
    if k.size:
        seg = problem.segments()[k]
        r = _spread(m, k, socket_rates_from_swing(problem.body, w[k], seg))
    rates.append(r)
    twists.append(jnp.zeros((2, m), dtype))
    # A unit of every state twist turns every segment whose twist is the state's.
    own_twist = np.ones(m)
    own_twist[list(lay.spine)] = 0.0
    rates.append(jnp.zeros((1, m, 3), dtype))
    twists.append(jnp.asarray(own_twist[None], dtype))
    if spine is not None:
        r, t = _part_rates(problem, spine_frames, spine, np.eye(3))
        rates.append(r)
        twists.append(t)
    if lay.root:
        r, t = _part_rates(problem, root_frame, root, np.eye(6))
        rates.append(r)
        twists.append(t)
    n_root = root.shape[0]
    shifts = np.zeros((sum(a.shape[0] for a in rates), 3))
    if n_root:
        shifts[-n_root:][:3] = np.eye(3)
    return jnp.concatenate(rates), jnp.concatenate(twists), jnp.asarray(shifts, dtype)


def _unknown_slots(lay: Layout) -> tuple[np.ndarray, slice]:
    """(n_free,) the chain slot of the one segment each unknown turns (static), and the
    slice of the spine target's three, which turn every vertebra."""
    n_spine = 3 if lay.spine else 0
    root = [lay.chain.position(0)] * 6 if lay.root else []
    slots = list(lay.swing_x + lay.swing_y + lay.twist) + [0] * n_spine + root
    start = len(lay.swing_x + lay.swing_y + lay.twist)
    return np.asarray(slots, int), slice(start, start + n_spine)


def point_jacobian(problem, slots, x: Array, p: Array, links, frac: Array) -> Array:
    """d points / d x (k, 3, n_free) in closed form: an unknown turning segment i at rate
    w (world) moves a point below i by w x (p - c_i), c_i its proximal joint (its own
    segment's twist by the point's share `frac`)."""
    lay = problem.layout
    rates, twists, shifts = _unit_rates(problem, x)
    dw, dtau, d_spine, d_root = jax.jacfwd(problem.state)(x)
    m, n = dtau.shape
    # Per unit tangent, its coefficient for each chain segment and unknown (g, m, n).
    coef = [dw[:, 0], dw[:, 1], dtau]
    for part in (d_spine, d_root):
        if part is not None:
            coef += [jnp.broadcast_to(row, (m, n)) for row in part]
    coef = jnp.stack(coef)
    R_base, Z, c = links.R_base, links.R_base[:, :, 2], links.p_proximal
    turn = jnp.einsum("mab,gmn,gmb->man", R_base, coef, rates)  # (m, 3, n) world rates
    spin = jnp.einsum("gmn,gm->mn", coef, twists)[:, None, :] * Z[:, :, None]
    on_path, own = _ancestry(lay, slots)
    in_chain = jnp.asarray(on_path.any(1), p.dtype)
    shift = in_chain[:, None, None] * jnp.einsum("gn,ga->an", coef[:, 0], shifts)[None]
    share = jnp.where(jnp.asarray(own, bool), frac[:, None], 1.0)  # (k, m) of the twist
    unknown, spine = _unknown_slots(lay)
    cols = np.arange(n)
    single = np.setdiff1d(cols, cols[spine])
    # One segment per unknown: gather it, no sum over the chain.
    rot = turn[unknown, :, cols][None] + share[:, unknown][:, :, None] * spin[unknown, :, cols]
    J = jnp.asarray(on_path[:, unknown], p.dtype)[:, :, None] * jnp.cross(
        rot, p[:, None] - c[unknown][None]
    )
    J = jnp.swapaxes(J, 1, 2)
    if spine.stop > spine.start:
        # The spine target's three turn every vertebra: sum over them.
        vertebrae = np.asarray(lay.spine, int)
        w = turn[vertebrae][..., cols[spine]]  # (s, 3, 3)
        t = spin[vertebrae][..., cols[spine]]
        lever = p[:, None, :] - c[vertebrae][None]  # (k, s, 3)
        r = w[None] + share[:, vertebrae][:, :, None, None] * t[None]  # (k, s, 3, u)
        arm = jnp.cross(jnp.moveaxis(r, 2, -1), lever[:, :, None, :])  # (k, s, u, 3)
        moved = jnp.einsum("ks,ksua->kau", jnp.asarray(on_path[:, vertebrae], p.dtype), arm)
        J = jnp.concatenate([J[..., : spine.start], moved, J[..., spine.stop :]], axis=-1)
    else:
        J = J[..., single]
    return J + shift


def _tree_points_jvp(primals, tangents):
    slots, problem, lengths, offsets, heights, x = primals
    _, d_problem, d_lengths, d_offsets, d_heights, dx = tangents
    quiet = all(_zero(t) for t in jax.tree.leaves(d_problem, is_leaf=_zero))
    if not (quiet and _closed_form(problem)):
        # Derivatives with respect to the problem, or a re-rooted body: plain autodiff.
        tangents = jax.tree.map(
            lambda t, a: jnp.zeros_like(a) if _zero(t) else t,
            tangents[1:],
            primals[1:],
            is_leaf=_zero,
        )
        fn = lambda *a: walk_points(a[0], slots, *a[1:])[0]  # noqa: E731
        return jax.jvp(fn, primals[1:], tangents)
    p, links, tau = walk_points(problem, slots, lengths, offsets, heights, x)
    lay = problem.layout
    slot, seg = slots, take(problem.slot_segments(), slots)
    L = lengths[seg]
    frac = twist_fraction(heights, L)
    safe_L = jnp.where(L > 0, L, 1.0)  # a segment of length 0 has no twist share to change
    dp = jnp.zeros_like(p)
    if not _zero(dx):
        dp = dp + jnp.einsum("kau,u->ka", point_jacobian(problem, slots, x, p, links, frac), dx)
    # Lengths, offsets and heights (the scale fits): a longer segment moves the joints below
    # it along its axis; a point's share z / length of its segment's twist changes with
    # both. Base segments stay where the start put them.
    allof = jax.tree.map(lambda c, s: jnp.concatenate([c, s]), links, problem.bases)
    R, c = allof.R_base[slot], allof.p_proximal[slot]
    twist = jnp.concatenate([tau, problem.tau_bases])[slot]
    d_frac = jnp.zeros_like(frac)
    if not _zero(d_lengths):
        on_path, own = (jnp.asarray(a, p.dtype) for a in _ancestry(lay, slots))
        dL = d_lengths[problem.segments()]
        dp = dp + (on_path - own) @ (dL[:, None] * links.R_base[:, :, 2])
        d_frac = d_frac - heights * d_lengths[seg] / safe_L**2
    if not _zero(d_offsets):
        body = eqx.tree_at(lambda b: b.lengths, problem.body, lengths)
        dp = dp + place_on_segments(body, seg, d_offsets, heights, R, twist)
    if not _zero(d_heights):
        d_frac = d_frac + d_heights / safe_L
    d_angle = jnp.where((heights > 0) & (heights < L), d_frac * twist, 0.0)
    dp = dp + d_angle[:, None] * jnp.cross(R[:, :, 2], p - c)
    return p, dp


_tree_points.defjvp(_tree_points_jvp, symbolic_zeros=True)
