"""Constraints of a reach (docs/design.md, section 10): no contact, feet on the floor,
balance. Host-side `Target`s are merged into one `Constraints` pytree of index arrays; its
rows are residuals on the same point kernel as the targets (`Problem.effectors` places the
spheres and centroids they read in the one walk), weighted `WEIGHT` times a target's.

- no contact: one row per checked pair of segments (`diffbody.contact`, closest spheres
  less their rest overlap) and per segment and environment shape: relu(margin - gap);
- on the floor: the sole spheres' centres stay at their planted place (3 rows each);
- balance: the centre of gravity's ground projection at least `margin` inside every edge
  of the support polygon of the sole spheres: relu(margin - inside) per candidate edge.
"""

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._body import Body, Pose
from .._body_cache import RANGES, BodyCache
from .._device_arrays import device_array
from .._kinematics import forward
from .._programs import compiled, is_traced
from ..contact._distances import closest_pair_gaps, environment_gaps
from ..contact._environment import Environment
from ..contact._pairs import sphere_pairs
from ..contact._support import sole_spheres, support_edges

# A constraint row weighs this many times a target's: a target missed by 10 cm leaves a
# constraint violated by about 0.1 mm (the penalty's balance, 10 cm / WEIGHT^2).
WEIGHT = 50.0
KINDS = ("no_contact", "on_floor", "balance")
# The arrays the host work reads (which pairs, which soles): the standard geometry, the limits.
GEOMETRY = ("lengths", "R_socket_rest", "rest_position", "sphere_origins", "sphere_radii", *RANGES)


class Constraints(eqx.Module):
    """The merged constraints of one problem. `spheres`: the spheres whose centres the
    rows read (static); pair and sole indices point into it."""

    kinds: tuple[str, ...] = eqx.field(static=True)  # which of KINDS are present
    spheres: tuple[int, ...] = eqx.field(static=True)
    segments: tuple[int, ...] = eqx.field(static=True)  # segments read (not moved)
    feet: tuple[int, ...] = eqx.field(static=True)  # segments standing on the floor
    n_pair_groups: int = eqx.field(static=True)
    pair_a: Int[Array, " P"]
    pair_b: Int[Array, " P"]
    pair_group: Int[Array, " P"]
    allowance: Float[Array, " P"]
    pair_margin: Float[Array, ""]
    env: Environment
    env_sphere: Int[Array, " K"]  # into `spheres`
    env_group: Int[Array, " K"]  # row of the sphere's segment
    n_env_groups: int = eqx.field(static=True)
    env_margin: Float[Array, "n_env_seg n_shape"]  # m; OFF where no target asks
    sole: Int[Array, " F"]  # into `spheres`
    sole_height: Float[Array, " F"]  # m, the floor each sole sphere stands on
    sole_center: Float[Array, "F 3"]  # m, where each sole sphere's centre stays
    edge_normal: Float[Array, "E 2"]
    edge_offset: Float[Array, " E"]
    edge: Array  # (E,) bool
    balance_margin: Float[Array, ""]

    @property
    def balance(self) -> bool:
        return "balance" in self.kinds


def is_constraint(t) -> bool:
    return t.kind in KINDS


def _segments(body: Body, names) -> list[int]:
    return list(range(body.n_segments)) if names is None else [body.segment_index(n) for n in names]


def resolve_constraints(body: Body, targets: Sequence, init: Pose) -> Constraints | None:
    """The constraint targets (`Target.no_contact`, `.on_floor`, `.balance`) merged, their
    floor places taken from `init` (traceable in `init`). None when there are none. The
    host work (which pairs, which spheres) is cached per body geometry and constraints."""
    targets = [t for t in targets if is_constraint(t)]
    if not targets:
        return None
    key = tuple(target_key(t) for t in targets)
    c = _HOST.get(body, key, lambda: _host_constraints(body, targets))
    if not c.sole.shape[0]:
        return c
    return (_plant_jit if is_traced(body, c, init) else _plant)(body, c, init)


_HOST = BodyCache(GEOMETRY, size=128)


def target_key(t) -> tuple:
    env = (
        None
        if t.environment is None
        else tuple(np.asarray(a).tobytes() for a in jax.tree.leaves(t.environment))
    )
    return (t.kind, t.segments, t.margin, _plain(t.height), t.self_contact, env)


def _plain(x):
    return ("traced", id(x)) if isinstance(x, jax.core.Tracer) else float(x)


def _host_constraints(body: Body, targets: Sequence) -> Constraints:
    """`resolve_constraints` without `init`: the soles' places are filled by `_plant`."""
    dtype = jnp.result_type(float)
    kinds = tuple(k for k in KINDS if any(t.kind == k for t in targets))
    contact = [t for t in targets if t.kind == "no_contact"]
    floors = [t for t in targets if t.kind == "on_floor"]
    balance = [t for t in targets if t.kind == "balance"]
    if balance and not floors:
        raise ValueError(
            "Target.balance: the support polygon needs the feet on the floor; add "
            "Target.on_floor() (or solve_reach's standing=True adds both)"
        )
    # Self contact: the union of every target's pairs.
    selfish = [t for t in contact if t.self_contact]
    named: set[int] = set()
    everything = any(t.segments is None for t in selfish)
    for t in selfish:
        named |= set(_segments(body, t.segments))
    self_pairs = (
        sphere_pairs(body, None if everything else [body.segment_names[s] for s in sorted(named)])
        if selfish
        else None
    )
    env_targets = [t for t in contact if t.environment is not None and t.environment.n_shapes]
    env = _merged([t.environment for t in env_targets])
    env_segs = sorted({s for t in env_targets for s in _segments(body, t.segments)})
    seg_of = np.asarray(body.sphere_segment, int)
    env_spheres = [k for k in range(body.n_spheres) if seg_of[k] in set(env_segs)]
    stands = [_floor_segments(body, t) for t in floors]
    feet = sorted({s for segs in stands for s in segs})
    soles = sole_spheres(body, [body.segment_names[s] for s in feet]) if feet else np.zeros(0, int)
    used = set(env_spheres) | set(soles.tolist())
    if self_pairs is not None:
        used |= set(self_pairs.i.tolist()) | set(self_pairs.j.tolist())
    spheres = tuple(sorted(used))
    where = {k: n for n, k in enumerate(spheres)}
    remap = np.vectorize(where.__getitem__, otypes=[int])
    empty = np.zeros(0, int)
    heights = {s: t.height for t, segs in zip(floors, stands) for s in segs}
    n_sole = len(soles)
    read = {seg_of[s] for s in spheres} | (set(range(body.n_segments)) if balance else set())
    if any(isinstance(heights[seg_of[s]], jax.core.Tracer) for s in soles):
        sole_height = jnp.stack([jnp.asarray(heights[seg_of[s]], dtype) for s in soles])
    else:
        sole_height = device_array([heights[seg_of[s]] for s in soles])
    return Constraints(
        kinds=kinds,
        spheres=spheres,
        segments=tuple(sorted(int(s) for s in read)),
        feet=tuple(feet),
        n_pair_groups=0 if self_pairs is None else len(self_pairs.segments),
        pair_a=device_array(empty if self_pairs is None else remap(self_pairs.i), int),
        pair_b=device_array(empty if self_pairs is None else remap(self_pairs.j), int),
        pair_group=device_array(empty if self_pairs is None else self_pairs.segment_pair, int),
        allowance=device_array(np.zeros(0) if self_pairs is None else self_pairs.allowance),
        pair_margin=device_array(max([t.margin for t in selfish], default=0.0)),
        env=env,
        env_sphere=device_array(remap(env_spheres) if env_spheres else empty, int),
        env_group=device_array([env_segs.index(seg_of[s]) for s in env_spheres], int),
        n_env_groups=len(env_segs),
        env_margin=device_array(_env_margins(body, env_targets, env_segs)),
        sole=device_array(remap(soles) if n_sole else empty, int),
        sole_height=sole_height,
        sole_center=device_array(np.zeros((n_sole, 3))),
        edge_normal=device_array(np.zeros((n_sole**2, 2))),
        edge_offset=device_array(np.zeros(n_sole**2)),
        edge=device_array(np.zeros(n_sole**2, bool), bool),
        balance_margin=device_array(max([t.margin for t in balance], default=0.0)),
    )


def _floor_segments(body: Body, t) -> list[int]:
    """The segments an `on_floor` target stands on: those it names, else the body's feet."""
    if t.segments is not None:
        return _segments(body, t.segments)
    if not body.feet:
        raise ValueError(
            "Target.on_floor: the body has no feet (segments named '*_foot'); name the "
            "segments to stand on"
        )
    return list(body.feet)


def _plant(body: Body, c: Constraints, init: Pose) -> Constraints:
    """The soles' places: their centres in `init` lowered or raised onto their floor, and
    the support polygon's candidate edges. With concrete inputs, from the compiled `forward`
    that every pose of the body structure shares and the rest in NumPy (a program of its own
    would compile for set-up only; docs/design.md, section 9, "Host set-up")."""
    traced = is_traced(body, c, init)
    xp = jnp if traced else np
    k = forward(body, init)
    idx = xp.asarray(c.spheres)[xp.asarray(c.sole)]
    z = xp.asarray(c.sole_height) + xp.asarray(body.sphere_radii)[idx]
    center = xp.concatenate([xp.asarray(k.sphere_centers)[idx, :2], z[:, None]], axis=1)
    planted = (center, *support_edges(center[:, :2]))
    return eqx.tree_at(
        lambda c: (c.sole_center, c.edge_normal, c.edge_offset, c.edge),
        c,
        planted if traced else tuple(jax.device_put(a) for a in planted),
    )


_plant_jit = eqx.filter_jit(_plant)  # traced: one program, not op by op under jax.grad


# The margin of a segment and shape that no target pairs: its row never binds.
OFF = -1e6


def _env_margins(body: Body, targets: list, env_segs: list[int]) -> np.ndarray:
    """(segments, shapes) the margin each segment keeps from each shape of the merged
    environment (`_merged`: planes, spheres, capsules, boxes, each kind in target order):
    the largest of the targets that name both, OFF where none does."""
    kinds = ("planes", "spheres", "capsules", "boxes")
    counts = np.asarray([[getattr(t.environment, k).shape[0] for k in kinds] for t in targets])
    counts = counts.reshape(-1, 4)
    start = np.concatenate([[0], np.cumsum(counts.sum(0))[:-1]])  # each kind's first column
    out = np.full((len(env_segs), int(counts.sum())), OFF)
    for n, t in enumerate(targets):
        rows = [env_segs.index(s) for s in _segments(body, t.segments)]
        for k in range(4):
            first = start[k] + counts[:n, k].sum()
            cols = np.arange(first, first + counts[n, k])
            out[np.ix_(rows, cols)] = np.maximum(out[np.ix_(rows, cols)], t.margin)
    return out


def _merged(envs: list[Environment]) -> Environment:
    if not envs:
        return Environment.of()
    return jax.tree.map(lambda *a: device_array(np.concatenate(a)), *envs)


def constraint_rows(
    c: Constraints, centers: Array, radii: Array, cog: Array | None
) -> tuple[Array, Array]:
    """Unweighted residual rows of the constraints (m) and each kind's violation (m, in
    `c.kinds` order: the largest row of the kind), from the centres of `c.spheres`
    (k, 3), their radii and the centre of gravity (3,) (None without balance)."""
    rows, worst = [], []
    if "no_contact" in c.kinds:
        parts = []
        if c.n_pair_groups:
            gap, _ = closest_pair_gaps(
                centers, radii, c.pair_a, c.pair_b, c.allowance, c.pair_group, c.n_pair_groups
            )
            parts.append(jax.nn.relu(c.pair_margin - gap))
        if c.n_env_groups:
            gap, _ = environment_gaps(
                centers[c.env_sphere], radii[c.env_sphere], c.env, c.env_group, c.n_env_groups
            )
            parts.append(jax.nn.relu(c.env_margin - gap).ravel())  # OFF: never binds
        r = jnp.concatenate(parts) if parts else jnp.zeros(0, centers.dtype)
        rows.append(r)
        worst.append(jnp.max(r, initial=0.0))
    if "on_floor" in c.kinds:
        d = centers[c.sole] - c.sole_center
        rows.append(d.ravel())
        worst.append(jnp.max(jnp.sqrt(jnp.sum(d * d, -1) + 1e-30), initial=0.0))
    if "balance" in c.kinds:
        inside = c.edge_offset - c.edge_normal @ cog[:2]
        r = jnp.where(c.edge, jax.nn.relu(c.balance_margin - inside), 0.0)
        rows.append(r)
        worst.append(jnp.max(r, initial=0.0))
    return jnp.concatenate(rows), jnp.stack(worst)


def row_count(c: Constraints | None) -> int:
    """The number of `constraint_rows` (static), from their shapes alone: no walk traced."""
    if c is None:
        return 0
    k = len(c.spheres)
    rows = jax.eval_shape(
        lambda c: constraint_rows(c, jnp.zeros((k, 3)), jnp.zeros(k), jnp.zeros(3))[0], c
    )
    return rows.shape[0]


def pose_violations(body: Body, pose: Pose, c: Constraints | None) -> Array:
    """Each constraint kind's violation (m) in a pose, from `forward`: what the result
    reports, whichever phase solved it. With a concrete pose, `forward`'s one program per
    body and a small one per constraint set (`_worst`): a conclusion that leaves the
    constraints out is one program for every constraint set."""
    if c is None:
        return jnp.zeros(0)
    k = forward(body, pose)
    idx = np.asarray(c.spheres, int)
    if is_traced(body, pose, c):
        return _worst(c, k.sphere_centers[idx], k.sphere_radii[idx], k.center_of_gravity)
    # On the host: NumPy's indexing compiles nothing (a device array's would, per shape).
    centers, radii, cog = (
        np.asarray(a) for a in (k.sphere_centers, k.sphere_radii, k.center_of_gravity)
    )
    return _worst_jit(c, centers[idx], radii[idx], cog)


def _worst(c: Constraints, centers: Array, radii: Array, cog: Array) -> Array:
    """Each kind's violation (`constraint_rows`)."""
    return constraint_rows(c, centers, radii, cog)[1]


_worst_jit = compiled(_worst)
