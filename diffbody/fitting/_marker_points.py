"""The marker point kernel: motion-capture markers' world positions on the walked body
(`tree_markers`, (n, 3) m for the posture's free vector, one walk of the layout's chain) and
their closed-form Jacobian (docs/design.md, sections 6 and 7).

Its custom JVP uses the walk's own output instead of autodiff's one tangent per unknown: an
unknown turning segment i at world rate w moves every point below i by w x (p - c_i), c_i
the segment's proximal joint, and a marker on i itself by its share z / length of i's
twist; the rates come from the walk-free part of the posture (`socket_state`). So a Jacobian
costs one walk and a few small products.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, Float

from .._kinematics import (
    exp_swing,
    place_on_segments,
    socket_frames_from_swing,
    spine_deviation,
    twist_fraction,
    walk_links,
    world_base,
)
from .._rotations import exp_rotvec, matmul3
from ..ik._problem import Problem
from ._marker_layout import MocapLayout


def socket_state(problem: Problem, x: Array) -> tuple[Array, Array, Array]:
    """The free vector x as every chain segment's base frame in its socket (m, 3, 3, chain
    order), its twist (m,) and the root joint's position (3,): what `Problem.links` walks.
    Walk-free, so that its derivatives cost little."""
    return _socket_frames(problem, problem.state(x))


def _socket_frames(problem: Problem, state: tuple) -> tuple[Array, Array, Array]:
    """`socket_state` from the problem's state (swing vectors, twists, spine target, root
    placement: `Problem.state`). Each part below gives (chain rows, their base frames in
    their sockets, their twists or None: the state's); the last part naming a row wins."""
    lay = problem.layout
    w, tau, spine_target, root = state
    m = lay.chain.size
    parts = [(np.arange(m), problem.R_socket0, tau)]
    parts += _swing_frames(problem, w) + _spine_frames(problem, spine_target)
    parts += _root_frame(problem, root)
    R = jnp.concatenate([f for _, f, _ in parts])[_last_of(m, [k for k, _, _ in parts])]
    twisted = [(k, t) for k, _, t in parts if t is not None]
    tau = jnp.concatenate([t for _, t in twisted])[_last_of(m, [k for k, _ in twisted])]
    position = problem.position0 + root[:3] if lay.root else problem.position0
    return R, tau, position


def _swing_frames(problem: Problem, w: Array) -> list:
    """The frames of the segments with a free swing or twist."""
    lay = problem.layout
    k = np.asarray(sorted(set(lay.swing_x + lay.swing_y + lay.twist)), int)
    if not k.size:
        return []
    seg = np.asarray(lay.chain.segments, int)[k]
    return [(k, socket_frames_from_swing(problem.body, w[k], seg), None)]


def _spine_frames(problem: Problem, spine_target: Array | None) -> list:
    """The frames and twists of the vertebrae, bent to the spine target (Bendspine)."""
    lay, b = problem.layout, problem.body
    if not lay.spine:
        return []
    _, w_sp, tw_sp = spine_deviation(b, spine_target)
    k, r = np.asarray(lay.spine, int), np.asarray(lay.spine_rows, int)
    seg = np.asarray(lay.chain.segments, int)[k]
    return [(k, matmul3(b.R_socket_rest[seg], exp_swing(w_sp[r])), tw_sp[r])]


def _root_frame(problem: Problem, root: Array) -> list:
    """The whole body's frame, turned by the root's rotation vector about the root joint."""
    lay = problem.layout
    if not lay.root:
        return []
    k0 = np.asarray([lay.chain.position(0)])
    return [(k0, matmul3(exp_rotvec(root[3:])[None], problem.R_socket0[k0]), None)]


def _last_of(m: int, rows: list[np.ndarray]) -> np.ndarray:
    """(m,) for each of m rows, its place in the concatenation of parts whose rows are
    `rows`: the last part naming a row wins (a gather, no scatter)."""
    pick, offset = np.zeros(m, int), 0
    for r in rows:
        pick[r] = offset + np.arange(len(r))
        offset += len(r)
    return pick


def _ancestry(lay: MocapLayout) -> tuple[np.ndarray, np.ndarray]:
    """(n, m) static masks over the chain: chain segment i on marker k's path to the top
    (itself included), and i being marker k's own segment."""
    chain = lay.pose.chain
    parent = {k: p for k, p in enumerate(chain.parent_slot) if p < chain.size}
    on_path = np.zeros((len(lay.slots), chain.size))
    for k, s in enumerate(lay.slots):
        while s is not None:
            on_path[k, s] = 1.0
            s = parent.get(s)
    own = np.zeros_like(on_path)
    own[np.arange(len(lay.slots)), list(lay.slots)] = 1.0
    return on_path, own


def _walk_markers(problem: Problem, lay: MocapLayout, lengths: Array, offsets: Array, x: Array):
    """World markers (n, 3), the chain's links and base frames in their sockets and twists,
    for the posture x with segment `lengths` (n_seg,): one walk."""
    body = eqx.tree_at(lambda b: b.lengths, problem.body, lengths)
    R_sb, tau, position = socket_state(problem, x)
    links = walk_links(body, lay.pose.chain, R_sb, tau, world_base(position))
    slot, seg = np.asarray(lay.slots, int), np.asarray(lay.segments, int)
    local = place_on_segments(body, seg, offsets, offsets[:, 2], links.R_base[slot], tau[slot])
    return links.p_proximal[slot] + local, links, R_sb, tau


def _walkable(lay: MocapLayout) -> bool:
    """Whether the chain hangs from the world alone (not a re-rooted body): then
    `tree_markers` has its closed-form derivatives."""
    return lay.pose.bases == (-1,) and not lay.pose.full


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def tree_markers(
    lay: MocapLayout,
    problem: Problem,
    lengths: Float[Array, " n_seg"],
    offsets: Float[Array, "n 3"],
    x: Float[Array, " n_free"],
) -> Float[Array, "n 3"]:
    """World positions (m) of markers at `offsets` (their segments' cross of axes) on the
    problem's body with segment `lengths`, for the posture's free vector x: one walk of the
    layout's chain.

    Its derivatives are in closed form (docs/design.md, section 6: a rotation rate w about a joint c
    moves a point p below it by w x (p - c)), with the rates of the segments' frames in
    their sockets from the walk-free `socket_state`: a Jacobian costs one walk instead of
    one per unknown."""
    return _walk_markers(problem, lay, lengths, offsets, x)[0]


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


def _part_rates(problem: Problem, part, value: Array, units: np.ndarray) -> tuple[Array, Array]:
    """Body rates (u, m, 3), vee(R^T dR) of the base frames in their sockets, and twist
    rates (u, m) of the frames a part of the state makes (`_socket_frames`), per unit
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


def _unit_rates(problem: Problem, x: Array) -> tuple[Array, Array, Array]:
    """Per unit tangent of the problem's state, every chain segment's body rate (g, m, 3),
    twist rate (g, m) and the root joint's shift (g, 3), for g = 12 unit tangents: the
    swing vectors' w_x and w_y (all segments at once), the twists, the spine target's 3
    and the root's 6 components. Each part of the state moves only its own segments'
    frames, and each of those frames only by its own entries (the Jacobian is
    block-diagonal), so these 12 derivative passes, each through one part, give every
    rate, where autodiff would carry one tangent per unknown through every part."""
    lay = problem.layout
    w, tau, spine, root = problem.state(x)
    m, dtype = lay.chain.size, tau.dtype
    rates, twists = [], []
    r, t = _part_rates(problem, _swing_frames, w, np.eye(2)[:, None, :] * np.ones((m, 1)))
    rates.append(r)
    twists.append(t)
    # A unit of every state twist turns every segment whose twist is the state's.
    own_twist = np.ones(m)
    own_twist[list(lay.spine)] = 0.0
    rates.append(jnp.zeros((1, m, 3), dtype))
    twists.append(jnp.asarray(own_twist[None], dtype))
    if spine is not None:
        r, t = _part_rates(problem, _spine_frames, spine, np.eye(3))
        rates.append(r)
        twists.append(t)
    if lay.root:
        r, t = _part_rates(problem, _root_frame, root, np.eye(6))
        rates.append(r)
        twists.append(t)
    n_root = root.shape[0]
    shifts = np.zeros((sum(a.shape[0] for a in rates), 3))
    if n_root:
        shifts[-n_root:][:3] = np.eye(3)
    return jnp.concatenate(rates), jnp.concatenate(twists), jnp.asarray(shifts, dtype)


def _unknown_slots(lay: MocapLayout) -> tuple[np.ndarray, slice]:
    """(n_free,) the chain slot of the one segment each unknown turns (static), and the
    slice of the spine target's three, which turn every vertebra."""
    p = lay.pose
    n_spine = 3 if p.spine else 0
    root = [p.chain.position(0)] * 6 if p.root else []
    slots = list(p.swing_x + p.swing_y + p.twist) + [0] * n_spine + root
    start = len(p.swing_x + p.swing_y + p.twist)
    return np.asarray(slots, int), slice(start, start + n_spine)


def _pose_jacobian(problem: Problem, lay: MocapLayout, x: Array, p: Array, links, frac: Array):
    """d markers / d x (n, 3, n_free) in closed form: an unknown turning segment i at rate
    w (world) moves a marker below i by w x (p - c_i), c_i its proximal joint (its own
    segment's twist by the marker's share z / length)."""
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
    shift = jnp.einsum("gn,ga->an", coef[:, 0], shifts)
    on_path, own = _ancestry(lay)
    share = jnp.where(jnp.asarray(own, bool), frac[:, None], 1.0)  # (k, m) of the twist

    def moved(slots, cols):
        """(k, 3, len(cols)): the markers' motion by unknowns `cols`, summed over the
        chain slots `slots` (k, s) ... each unknown turns."""
        w = turn[slots][..., cols]  # (s, 3, u)
        t = spin[slots][..., cols]
        lever = p[:, None, :] - c[slots][None]  # (k, s, 3)
        rot = w[None] + share[:, slots][:, :, None, None] * t[None]  # (k, s, 3, u)
        arm = jnp.cross(jnp.moveaxis(rot, 2, -1), lever[:, :, None, :])  # (k, s, u, 3)
        return jnp.einsum("ks,ksua->kau", jnp.asarray(on_path[:, slots], p.dtype), arm)

    slots, spine = _unknown_slots(lay)
    cols = np.arange(n)
    single = np.setdiff1d(cols, cols[spine])
    # One segment per unknown: gather it, no sum over the chain.
    w = turn[slots, :, cols]  # (n, 3)
    t = spin[slots, :, cols]
    rot = w[None] + share[:, slots][:, :, None] * t[None]  # (k, n, 3)
    J = jnp.asarray(on_path[:, slots], p.dtype)[:, :, None] * jnp.cross(
        rot, p[:, None] - c[slots][None]
    )
    J = jnp.swapaxes(J, 1, 2)[:, :, single]
    parts = [J[..., : spine.start], None, J[..., spine.start :]]
    if spine.stop > spine.start:
        vertebrae = np.asarray(lay.pose.spine, int)
        parts[1] = moved(vertebrae, cols[spine])
    J = jnp.concatenate([q for q in parts if q is not None], axis=-1)
    return J + shift[None]


def _tree_markers_jvp(lay: MocapLayout, primals, tangents):
    problem, lengths, offsets, x = primals
    d_problem, d_lengths, d_offsets, dx = tangents
    if not _walkable(lay) or not all(_zero(t) for t in jax.tree.leaves(d_problem, is_leaf=_zero)):
        # A re-rooted body, or derivatives with respect to the problem: plain autodiff.
        tangents = jax.tree.map(
            lambda t, a: jnp.zeros_like(a) if _zero(t) else t, tangents, primals, is_leaf=_zero
        )
        fn = lambda *a: _walk_markers(*a[:1], lay, *a[1:])[0]  # noqa: E731
        return jax.jvp(fn, primals, tangents)
    p, links, _, tau = _walk_markers(problem, lay, lengths, offsets, x)
    slot, seg = np.asarray(lay.slots, int), np.asarray(lay.segments, int)
    z, L = offsets[:, 2], lengths[seg]
    frac = twist_fraction(z, L)
    dp = jnp.zeros_like(p)
    if not _zero(dx):
        dp = dp + jnp.einsum("kau,u->ka", _pose_jacobian(problem, lay, x, p, links, frac), dx)
    # Lengths and offsets (the static fit): a longer segment moves the joints below it along
    # its axis; a marker's share z / length of its segment's twist changes with both.
    on_path, own = (jnp.asarray(a, p.dtype) for a in _ancestry(lay))
    Z = links.R_base[:, :, 2]
    d_frac = jnp.zeros_like(frac)
    if not _zero(d_lengths):
        dL = d_lengths[np.asarray(lay.pose.chain.segments, int)]
        dp = dp + (on_path - own) @ (dL[:, None] * Z)
        d_frac = d_frac - z * d_lengths[seg] / L**2
    if not _zero(d_offsets):
        body = eqx.tree_at(lambda b: b.lengths, problem.body, lengths)
        dp = dp + place_on_segments(body, seg, d_offsets, z, links.R_base[slot], tau[slot])
        d_frac = d_frac + d_offsets[:, 2] / L
    d_angle = jnp.where((z > 0) & (z < L), d_frac * tau[slot], 0.0)
    dp = dp + d_angle[:, None] * jnp.cross(Z[slot], p - links.p_proximal[slot])
    return p, dp


tree_markers.defjvp(_tree_markers_jvp, symbolic_zeros=True)


def model_markers(
    problem: Problem, lay: MocapLayout, offsets: Float[Array, "n 3"], x: Array
) -> Float[Array, "n 3"]:
    """`tree_markers` on the problem's own body."""
    return tree_markers(lay, problem, problem.body.lengths, offsets, x)
