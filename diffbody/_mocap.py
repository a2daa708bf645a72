"""Motion capture (DESIGN section 7): a body scaled and its markers registered on a static
trial (`scale_and_register`), then the posture of every frame of a trial (`fit_motion`).

Both are weighted least squares over the reach core's unknowns (`_unknowns`: swing vectors
and twists within their limits through bounded maps, the spine as its Bendspine target,
the whole body's placement free), solved by optimistix's Levenberg-Marquardt on Cholesky
normal equations, with one walk of the marked segments per residual evaluation
(`Problem.links`). A marker rides on its segment like a sphere centre: turned by its share
z / length of the segment's twist (`place_on_segments`).

**Lean unknowns** (`mocap_layout`). Only the segments that carry a marker, or hold one
below them, are walked and move: the hands of a set without hand markers stay as in the
start. The neck is held as well when it carries no marker: with markers on the head only,
the neck's swing and the head's are one motion at marker resolution (OpenSim's Gait2354
has no neck either). For the shipped set on the default body: 37 unknowns.

**The static fit** (`scale_and_register`). Unknowns: the posture, the logarithms of the
axial scale factors of the 13 `SCALE_GROUPS` (left and right share one; radii stay) and
every marker's offset. Residual rows, each a standard score:
- each marker, sqrt(weight) (model - measured) / `MARKER_SD`;
- each marker's move from where the set puts it on the scaled body (the set's offsets scale
  with the body, `scale_offsets`) / its tolerance: bony landmarks stay close, soft-tissue
  markers may move;
- the population prior (`prior=True`): the ANSUR II log-Gaussian of one sex
  (`PopulationPrior.ansur2`), marginalised to the length measurements `PRIOR_MEASUREMENTS`
  and evaluated on the scaled body (`measure`), whitened by its covariance. So the answer
  is the maximum a posteriori body: the markers decide what they see, the population
  fills in the rest (the hands' length from the body's other lengths). Without the prior, a
  weak pull holds the scale factors no marker sees;
- a weak pull `PULL` of every posture unknown toward the start.
Start: the standard position moved rigidly (weighted Kabsch) so that the markers of the
rigid pelvis lie on the trial's mean frame.

**Every frame** (`fit_motion`). The body and offsets fixed, each frame's rows are
sqrt(weight) (model - measured) / `MARKER_SD` of its present markers (a missing marker
weighs 0 in its frame) and the pull toward the start. Measured on the shipped walk (151
frames, 41 markers, float32, 2 CPU cores), at equal accuracy: one vmapped solve of all
frames, each started from the registered static pose moved rigidly onto the frame's
pelvis markers, took FIXME; a `lax.scan` starting each frame from its predecessor's answer
took FIXME. The batched solve is kept; frames it leaves unconverged are solved again from
their nearest converged neighbour's answer.
"""

import dataclasses
import functools
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, Float, Int

from ._anthropometry import LENGTHS, _linear_model_jit
from ._batch import _Progress
from ._body import Body, Pose
from ._fitting import N_GROUPS, FitStatus, _anonymous, scaled
from ._kinematics import (
    exp_swing,
    place_on_segments,
    socket_frames_from_swing,
    spine_deviation,
    twist_fraction,
    walk_links,
    world_base,
)
from ._markers import MarkerTrial
from ._markerset import MarkerSet, match_markers, scale_offsets
from ._prior import PopulationPrior
from ._problem import Problem, make_problem
from ._rotations import exp_rotvec, matmul3
from ._scaling import per_segment
from ._unknowns import Layout, make_layout, path_to_top

FIT_CHOICES = ("lengths", "radii", "offsets")
MARKER_SD = 0.01  # m: a marker's rows are its error in units of this
PULL = 1e-3  # per unit of a free variable: an unobserved direction weighs as 10 um of error
# The prior's spread of each group's scale factor around the template's proportions: the
# measurements see sums of lengths (stature), not how the trunk splits between the lumbar
# and the thoracic spine; segment proportions vary by a few per cent between people.
PROPORTION_SD = 0.1
# With the radii: the breadths and depths of ANSUR II that the radial factors decide.
RADIAL_MEASUREMENTS = ("bideltoidbreadth", "hipbreadth", "chestdepth", "headlength")
MIN_MARKERS = 3  # a frame with fewer present markers cannot be placed: FAILED
# The length measurements of ANSUR II that the axial scale factors decide (they carry at
# least 80 % of each: tests/test_mocap.py). Breadths, depths and the weight depend on the
# radii and masses.
PRIOR_MEASUREMENTS = (
    "stature",
    "span",
    "acromialheight",
    "cervicaleheight",
    "sittingheight",
    "trochanterionheight",
    "kneeheightmidpatella",
    "lateralfemoralepicondyleheight",
    "tibialheight",
    "biacromialbreadth",
    "acromionradialelength",
    "radialestylionlength",
    "handlength",
    "footlength",
)
LINEAR_SOLVER = lx.Normal(lx.Cholesky())
STATIC_STEPS = 100
FRAME_STEPS = 100


def _solver(dtype) -> optx.LevenbergMarquardt:
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


# --- the unknowns ------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class MocapLayout:
    """What moves and where the markers ride (static): the reach layout of the marked
    segments, each marker's segment and its slot in the layout's chain, and which of
    [posture | log axial scales (n_group) | offset moves (n, 3)] are unknowns."""

    pose: Layout
    segments: tuple[int, ...]
    slots: tuple[int, ...]
    rigid: tuple[bool, ...]  # per marker: rides on the whole body rigidly (`rigid_markers`)
    fit: tuple[str, ...] = ()

    @property
    def sizes(self) -> tuple[int, int, int, int]:
        n_axial = N_GROUPS if "lengths" in self.fit else 0
        n_radial = N_GROUPS if "radii" in self.fit else 0
        n_offsets = 3 * len(self.segments) if "offsets" in self.fit else 0
        return self.pose.n_free, n_axial, n_radial, n_offsets

    def split(self, z: Array) -> tuple[Array, Array, Array, Array]:
        """The posture's free vector, the log axial and radial scales (zero when held) and
        the offset moves (n, 3; zero when held)."""
        x, log_axial, log_radial, moves = jnp.split(z, np.cumsum(self.sizes)[:-1])
        n = len(self.segments)
        zeros = jnp.zeros(N_GROUPS, z.dtype)
        log_axial = log_axial if self.sizes[1] else zeros
        log_radial = log_radial if self.sizes[2] else zeros
        moves = moves.reshape(n, 3) if self.sizes[3] else jnp.zeros((n, 3), z.dtype)
        return x, log_axial, log_radial, moves


def mocap_layout(body: Body, markerset: MarkerSet, fit: tuple[str, ...] = ()) -> MocapLayout:
    """The unknowns of a marker fit (module docstring): every segment on a marked segment's
    path to the top within its limits, except `FROZEN` segments that carry no marker; the
    spine as its Bendspine target; the whole body's placement."""
    marked = sorted(set(markerset.segments))
    movable = {s for m in marked for s in path_to_top(body, m)}
    points = [body.distal_joint[m] for m in marked]
    pose = make_layout(body, points, [], movable, spine=body.spine is not None, root=True)
    slot_of = dict(zip(marked, pose.point_slot))
    slots = tuple(slot_of[s] for s in markerset.segments)
    rigid = tuple(bool(r) for r in rigid_markers(body, markerset))
    return MocapLayout(pose, tuple(markerset.segments), slots, rigid, tuple(fit))


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

    Its derivatives are in closed form (DESIGN section 6: a rotation rate w about a joint c
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


# --- rigid starts ------------------------------------------------------------------------------
def rigid_fit(
    a: Float[Array, "n 3"], b: Float[Array, "n 3"], w: Float[Array, " n"]
) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
    """The rotation R and translation t minimising sum w |R a + t - b|^2 (weighted Kabsch,
    the SVD of the weighted cross-covariance with the reflection removed). No weight: the
    identity."""
    total = jnp.sum(w)
    wn = w / jnp.where(total > 0, total, 1.0)
    ca, cb = wn @ a, wn @ b
    H = (a - ca).T @ (wn[:, None] * (b - cb))
    U, _, Vt = jnp.linalg.svd(H)
    d = jnp.sign(jnp.linalg.det(Vt.T @ U.T))
    R = Vt.T @ jnp.diag(jnp.stack([1.0, 1.0, jnp.where(d == 0, 1.0, d)]).astype(a.dtype)) @ U.T
    ok = (total > 0) & jnp.all(jnp.isfinite(R))
    R = jnp.where(ok, R, jnp.eye(3, dtype=a.dtype))
    return R, jnp.where(ok, cb - R @ ca, 0.0)


def rotation_vector(R: Float[Array, "3 3"]) -> Float[Array, "3"]:
    """The rotation vector (axis times angle in [0, pi]) of a rotation matrix, through its
    unit quaternion (Shepperd: built from the largest of its four squared components, so
    well conditioned at every angle, a half turn included)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    a, b, c = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
    d, e, f = R[0, 1] + R[1, 0], R[0, 2] + R[2, 0], R[1, 2] + R[2, 1]
    # Rows: 4 q_k times the quaternion (w, x, y, z), for k = w, x, y, z.
    q = jnp.stack(
        [
            jnp.stack([1 + tr, a, b, c]),
            jnp.stack([a, 1 + 2 * R[0, 0] - tr, d, e]),
            jnp.stack([b, d, 1 + 2 * R[1, 1] - tr, f]),
            jnp.stack([c, e, f, 1 + 2 * R[2, 2] - tr]),
        ]
    )
    q = q[jnp.argmax(jnp.diagonal(q))]
    q = q * jnp.where(q[0] < 0, -1.0, 1.0) / jnp.linalg.norm(q)
    s = jnp.linalg.norm(q[1:])
    small = s < 1e-6
    angle_over_s = jnp.where(
        small, 2.0 / q[0], 2.0 * jnp.arctan2(s, q[0]) / jnp.where(small, 1.0, s)
    )
    return q[1:] * angle_over_s


def rigid_markers(body: Body, markerset: MarkerSet) -> np.ndarray:
    """(n,) which markers ride on the whole body rigidly: on segments whose path to the top
    has no range of motion (the pelvis of the default body), not moved by the spine."""
    spine = set(body.spine.segment_names) if body.spine is not None else set()
    ranges = np.concatenate(
        [
            np.asarray(body.swing_hi - body.swing_lo),
            np.asarray(body.twist_hi - body.twist_lo)[:, None],
        ],
        axis=1,
    )

    def rigid(s: int) -> bool:
        path = path_to_top(body, s)[:-1]  # without the whole body
        return all(np.all(ranges[p] == 0) and body.segment_names[p] not in spine for p in path)

    return np.asarray([rigid(s) for s in markerset.segments])


def _root_start(
    lay: MocapLayout, p_model: Array, target: Array, present: Array, position0: Array
) -> Array:
    """The root part (translation, rotation vector) of a free vector that moves the start
    rigidly onto `target`: fitted on the rigid markers when 3 of them are present, else on
    every present marker."""
    on_rigid = present & np.asarray(lay.rigid, bool)
    w = jnp.where(jnp.sum(on_rigid) >= 3, on_rigid, present).astype(p_model.dtype)
    R, t = rigid_fit(p_model, target, w)
    # Whole-body rotation R about the root joint p0 and a shift: p -> R (p - p0) + p0 + shift.
    return jnp.concatenate([t + R @ position0 - position0, rotation_vector(R)])


def _status(finite: Array, converged: Array) -> Array:
    return jnp.where(
        finite,
        jnp.where(converged, FitStatus.CONVERGED, FitStatus.NOT_CONVERGED),
        FitStatus.FAILED,
    )


# --- the static fit ----------------------------------------------------------------------------
class StaticFit(eqx.Module):
    """What `scale_and_register` returns."""

    body: Body  # the template scaled by the fitted factors
    pose: Pose  # the static posture (the spine as a Bendspine target)
    markerset: MarkerSet  # the registered offsets, for `body`
    axial: Float[Array, " n_group"]  # axial scale factors, `SCALE_GROUPS` order
    radial: Float[Array, " n_group"]  # radial scale factors (1 unless "radii" were fitted)
    errors: Float[Array, " n"]  # m, each marker's distance from its measured mean position
    status: Int[Array, ""]  # a FitStatus
    steps: Int[Array, ""]  # solver steps

    @property
    def converged(self) -> bool:
        return bool(self.status == FitStatus.CONVERGED)


class _Prior(eqx.Module):
    """The population prior's marginal of the measurements the fit changes, on the template
    scaled by axial and radial group factors s (2 n_group,): the measurements are A s,
    exactly within a piece (they are piecewise linear in the scale factors,
    `_anthropometry`), with their mean log values and whitening (the inverse Cholesky
    factor of their covariance)."""

    A: Float[Array, "k two_n_group"]  # m per unit factor: axial columns, then radial
    mean: Float[Array, " k"]
    whiten: Float[Array, "k k"]

    def rows(self, log_axial: Array, log_radial: Array) -> Array:
        """The whitened deviations of the log measurements, and each factor's deviation
        from the template's proportions (`PROPORTION_SD`): standard scores."""
        log_s = jnp.concatenate([log_axial, log_radial])
        log_m = jnp.log(self.A @ jnp.exp(log_s))
        return jnp.concatenate([self.whiten @ (log_m - self.mean), log_s / PROPORTION_SD])


def population_prior(prior, template: Body, sex: str | None, fit=FIT_CHOICES) -> _Prior | None:
    """The prior of the static fit (None: none) on `PRIOR_MEASUREMENTS`, and
    `RADIAL_MEASUREMENTS` when the radii are fitted. `prior`: True (every ANSUR II
    subject of `sex`; by default the sex the template's name starts with, male otherwise),
    False, or a `PopulationPrior`."""
    if prior is False or prior is None:
        return None
    if prior is True:
        if sex is None:
            sex = "female" if template.name.startswith("female") else "male"
        prior = PopulationPrior.ansur2(sex)
    if not isinstance(prior, PopulationPrior):
        raise TypeError(
            f"scale_and_register: prior must be True, False or a PopulationPrior, got {prior!r}"
        )
    names = PRIOR_MEASUREMENTS + (RADIAL_MEASUREMENTS if "radii" in fit else ())
    k = prior.index(names)
    whiten = np.linalg.inv(np.linalg.cholesky(prior.cov[np.ix_(k, k)]))
    dtype = template.lengths.dtype
    A = np.asarray(_linear_model_jit(_anonymous(template), jnp.ones(2 * N_GROUPS, dtype)))
    arrays = (A[[LENGTHS.index(n) for n in names]], prior.mean[k], whiten)
    return _Prior(*(jnp.asarray(a, dtype) for a in arrays))


class _Static(eqx.Module):
    """The fixed part of the static fit."""

    problem: Problem  # the posture's problem on the template, from the aligned start
    markerset: MarkerSet  # the set's offsets on the template
    target: Float[Array, "n 3"]  # m, measured mean positions (0 where missing)
    sqrt_w: Float[Array, " n"]  # sqrt(weight) / MARKER_SD, 0 where missing
    prior: _Prior | None


def _static_state(static: _Static, lay: MocapLayout, z: Array):
    """The segment lengths (n_seg,) and marker offsets (n, 3) on the scaled body, the
    posture's free vector, the log scales and the offsets' moves, for the unknowns z."""
    x, log_axial, log_radial, moves = lay.split(z)
    template = static.problem.body
    axial = per_segment(template, jnp.exp(log_axial))
    radial = per_segment(template, jnp.exp(log_radial))
    offsets = scale_offsets(static.markerset, template, axial, radial).offsets
    return template.lengths * axial, offsets + moves, x, (log_axial, log_radial), moves


def _static_residuals(z: Array, args) -> Array:
    """The static fit's rows (module docstring), standard scores."""
    static, lay = args
    lengths, offsets, x, log_scales, moves = _static_state(static, lay, z)
    p = tree_markers(lay, static.problem, lengths, offsets, x)
    rows = [
        (static.sqrt_w[:, None] * (p - static.target)).ravel(),
        (moves / static.markerset.tolerances[:, None]).ravel()[: lay.sizes[3]],
        PULL * (x - static.problem.x0),
    ]
    if static.prior is not None:
        rows.append(static.prior.rows(*log_scales))
    else:
        rows.append(PULL * jnp.concatenate(log_scales))
    return jnp.concatenate(rows)


def _fit_static(template: Body, lay: MocapLayout, rest: Pose, static: _Static):
    """The static solve: the start moved rigidly onto the pelvis markers, then every unknown
    at once. Returns the pose, log axial scales, offsets, per-marker errors, status, steps."""
    present = static.sqrt_w > 0
    x0 = static.problem.x0
    p0 = model_markers(static.problem, lay, static.markerset.offsets, x0)
    root = _root_start(lay, p0, static.target, present, static.problem.position0)
    init = static.problem.pose(x0.at[-6:].set(root), rest)
    static = dataclasses.replace(static, problem=make_problem(template, lay.pose, init))
    z0 = jnp.zeros(sum(lay.sizes), x0.dtype).at[: lay.sizes[0]].set(static.problem.x0)
    sol = optx.least_squares(
        _static_residuals, _solver(z0.dtype), z0, (static, lay), max_steps=STATIC_STEPS, throw=False
    )
    finite = jnp.all(jnp.isfinite(sol.value))
    z = jnp.where(finite, sol.value, z0)
    lengths, offsets, x, (log_axial, log_radial), _ = _static_state(static, lay, z)
    p = tree_markers(lay, static.problem, lengths, offsets, x)
    errors = jnp.where(present, jnp.linalg.norm(p - static.target, axis=-1), jnp.nan)
    status = _status(finite, sol.result == optx.RESULTS.successful)
    pose = static.problem.pose(x, init)
    return pose, log_axial, log_radial, offsets, errors, status, sol.stats["num_steps"]


_fit_static_jit = eqx.filter_jit(_fit_static)


def _fit_names(fit) -> tuple[str, ...]:
    fit = (fit,) if isinstance(fit, str) else tuple(fit)
    unknown = [f for f in fit if f not in FIT_CHOICES]
    if unknown:
        raise ValueError(
            f"scale_and_register: fit {unknown} is not a choice; give a subset of {FIT_CHOICES} "
            "(the posture always moves)"
        )
    return tuple(f for f in FIT_CHOICES if f in fit)


def _frame_arrays(trial: MarkerTrial, weights: np.ndarray, dtype) -> tuple[Array, Array]:
    """Targets (b, n, 3) m with NaN for a missing marker, and sqrt(weight) / MARKER_SD
    (b, n), 0 where missing."""
    pos = np.asarray(trial.positions, float)
    present = np.all(np.isfinite(pos), axis=-1)
    sqrt_w = np.where(present, np.sqrt(weights) / MARKER_SD, 0.0)
    return jnp.asarray(np.where(present[..., None], pos, np.nan), dtype), jnp.asarray(sqrt_w, dtype)


def _seen(target: Array) -> tuple[Array, Array]:
    """The targets with 0 for NaN (a row of weight 0 must not carry a NaN into the
    residuals) and whether each marker is present."""
    present = jnp.all(jnp.isfinite(target), axis=-1)
    return jnp.where(present[..., None], target, 0.0), present


def scale_and_register(
    body: Body,
    static: MarkerTrial,
    markerset: MarkerSet,
    *,
    prior=True,
    fit=FIT_CHOICES,
    sex: str | None = None,
) -> StaticFit:
    """Scale a body and register its markers on a static trial (module docstring).

    Args:
        body: the template (its markers' offsets are `markerset`'s, resolved for it).
        static: the static trial; its frames are averaged (`MarkerTrial.mean_frame`).
            Markers it lacks, or that the set does not map, are left out with a warning.
        markerset: the marker set resolved for `body` (`load_markerset`).
        prior: True: the ANSUR II population prior of `sex` on the body's length
            measurements (module docstring); a `PopulationPrior`; False: none.
        fit: what moves besides the posture: "lengths" (the log axial scale factors of
            `SCALE_GROUPS`) and "offsets" (each marker's offset).
        sex: "male" or "female" for `prior=True` (default: "female" when the body's name
            starts with it, else "male").

    Returns:
        A `StaticFit`: the scaled body, the static pose, the registered marker set (offsets
        for the scaled body; only the markers the trial has), the axial factors, each
        marker's distance (m) from its measured position, a FitStatus.
    """
    fit = _fit_names(fit)
    markerset, static = match_markers(markerset, static.mean_frame())
    template = _anonymous(body)
    lay = mocap_layout(template, markerset, fit)
    dtype = template.lengths.dtype
    target, sqrt_w = _frame_arrays(static, np.asarray(markerset.weights, float), dtype)
    if int(np.sum(np.asarray(sqrt_w) > 0)) < MIN_MARKERS:
        raise ValueError(
            f"scale_and_register: the static trial {static.source!r} has fewer than "
            f"{MIN_MARKERS} markers of the set {markerset.name!r} present; the body cannot "
            "be placed"
        )
    rest = template.rest_pose()
    state = _Static(
        problem=make_problem(template, lay.pose, rest),
        markerset=markerset,
        target=_seen(target[0])[0],
        sqrt_w=sqrt_w[0],
        prior=population_prior(prior, body, sex, fit),
    )
    out = _fit_static_jit(template, lay, rest, state)
    pose, log_axial, log_radial, offsets, errors, status, steps = out
    scaled_body = scaled(body, log_axial, log_radial)
    scaled_body = dataclasses.replace(
        scaled_body, name=f"{body.name}-scaled", source="diffbody.scale_and_register"
    )
    return StaticFit(
        body=scaled_body,
        pose=pose,
        markerset=eqx.tree_at(lambda m: m.offsets, markerset, offsets),
        axial=jnp.exp(log_axial),
        radial=jnp.exp(log_radial),
        errors=errors,
        status=status,
        steps=steps,
    )


# --- every frame -------------------------------------------------------------------------------
def _frame_residuals(x: Array, args) -> Array:
    problem, lay, offsets, target, sqrt_w, anchor = args
    p = model_markers(problem, lay, offsets, x)
    return jnp.concatenate([(sqrt_w[:, None] * (p - target)).ravel(), PULL * (x - anchor)])


def _solve_frame(problem, lay, offsets, x_start, anchor, target, sqrt_w):
    """One frame's posture from x_start, weakly pulled toward `anchor`: (x, status, steps).
    A frame with fewer than `MIN_MARKERS` markers keeps x_start (FAILED)."""
    sol = optx.least_squares(
        _frame_residuals,
        _solver(x_start.dtype),
        x_start,
        (problem, lay, offsets, target, sqrt_w, anchor),
        max_steps=FRAME_STEPS,
        throw=False,
    )
    ok = jnp.all(jnp.isfinite(sol.value)) & (jnp.sum(sqrt_w > 0) >= MIN_MARKERS)
    status = _status(ok, sol.result == optx.RESULTS.successful)
    return jnp.where(ok, sol.value, x_start), status, sol.stats["num_steps"]


def _fit_frames(problem, lay, offsets, measured, sqrt_w, x_first, init: Pose):
    """Every frame of a chunk, in order (lax.scan), each from its predecessor's answer,
    the first from x_first (NaN: from its anchor). Each frame's anchor is the start moved
    rigidly onto its rigid markers. Returns the poses, model markers, errors (NaN where
    missing), statuses, steps and the last free vector. measured: (b, n, 3), NaN where
    missing."""
    target, present = _seen(measured)
    p0 = model_markers(problem, lay, offsets, problem.x0)

    def anchor_of(t, w):
        root = _root_start(lay, p0, t, w > 0, problem.position0)
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
_make_problem_jit = eqx.filter_jit(make_problem)


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
    template = _anonymous(body)
    dtype = template.lengths.dtype
    lay = mocap_layout(template, markerset)
    problem = _make_problem_jit(template, lay.pose, start)
    offsets = jnp.asarray(markerset.offsets, dtype)
    target, sqrt_w = _frame_arrays(trial, w, dtype)
    total = trial.n_frames
    chunk = min(chunk_size, total)
    bar = _Progress(total, progress, "frames")
    outs = []
    x_last = jnp.full(lay.pose.n_free, jnp.nan, dtype)
    for lo in range(0, total, chunk):
        rows = np.minimum(np.arange(lo, lo + chunk), total - 1)  # pad with the last frame
        out = _fit_frames_jit(problem, lay, offsets, target[rows], sqrt_w[rows], x_last, start)
        *out, x_last = out
        keep = min(chunk, total - lo)
        outs.append(jax.tree.map(lambda a: np.asarray(a)[:keep], tuple(out)))
        bar.update(lo + keep)
    poses, p, err, status, steps = jax.tree.map(lambda *a: np.concatenate(a), *outs)
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
