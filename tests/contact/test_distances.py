"""Contact distances (diffbody.contact): against a brute-force NumPy loop over every sphere
pair and against closed forms; derivatives against finite differences, touching and
coincident spheres included; invariants of signed distances; which pairs are checked."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from limb_poses import random_limb_angles

import diffbody as db
from diffbody.contact import (
    Environment,
    closest_pair_gaps,
    contact_report,
    environment_gaps,
    sphere_distances,
    sphere_environment_distances,
    sphere_pairs,
)
from diffbody.contact._pairs import excluded_segment_pairs, rigid_groups

N_RANDOM = 4  # random poses within the limits, beside the standard position


@pytest.fixture(scope="module")
def body(male50):
    """The default body (`db.load_body()` is male50), shared with the session."""
    return male50


@pytest.fixture(scope="module")
def pairs(body):
    return sphere_pairs(body)


@pytest.fixture(scope="module")
def centers(body):
    """(1 + N_RANDOM, n_sph, 3) sphere centres (m): the standard position, then random
    postures of every segment within its swing and twist limits."""
    rng = np.random.default_rng(7)
    angles = random_limb_angles(body, body.segment_names, rng, N_RANDOM)
    angles = jnp.concatenate([body.rest_pose().angles[None], angles])
    fk = jax.jit(
        jax.vmap(lambda a: db.forward(body, db.Pose(body.rest_position, a)).sphere_centers)
    )
    return np.asarray(fk(angles))


def _distance_matrix(c: np.ndarray, r: np.ndarray) -> np.ndarray:
    return np.linalg.norm(c[:, None] - c[None], axis=-1) - r[:, None] - r[None]


def _brute_force(body, c: np.ndarray, c_rest: np.ndarray) -> dict[tuple[int, int], float]:
    """Per checked segment pair (a < b), the smallest signed distance less the rest overlap
    over every pair of their spheres, from the full distance matrices."""
    r = np.asarray(body.sphere_radii, float)
    seg = np.asarray(body.sphere_segment)
    d, rest = _distance_matrix(c, r), _distance_matrix(c_rest, r)
    gap = d - np.minimum(rest, 0.0)
    skip = excluded_segment_pairs(body)
    out = {}
    for a, b in itertools.combinations(range(body.n_segments), 2):
        ka, kb = np.flatnonzero(seg == a), np.flatnonzero(seg == b)
        if (a, b) in skip or not ka.size or not kb.size:
            continue
        out[(a, b)] = float(gap[np.ix_(ka, kb)].min())
    return out


def _gaps(c, r, p):
    return closest_pair_gaps(
        c,
        r,
        jnp.asarray(p.i),
        jnp.asarray(p.j),
        jnp.asarray(p.allowance),
        p.segment_pair,
        len(p.segments),
    )


# --- references: brute force ------------------------------------------------------------------
def test_rest_distances_are_the_standard_positions(body, pairs, centers):
    r = np.asarray(body.sphere_radii, float)
    d = _distance_matrix(centers[0], r)
    np.testing.assert_allclose(pairs.rest, d[pairs.i, pairs.j], rtol=0, atol=1e-12)


def test_closest_pair_gaps_match_a_brute_force_loop(body, pairs, centers):
    r = np.asarray(body.sphere_radii, float)
    gaps_fn = jax.jit(lambda c: _gaps(c, body.sphere_radii, pairs))
    for c in centers:
        expected = _brute_force(body, c, centers[0])
        assert {tuple(map(int, s)) for s in pairs.segments} == set(expected)
        gaps, k = map(np.asarray, gaps_fn(jnp.asarray(c)))
        want = np.asarray([expected[(int(a), int(b))] for a, b in pairs.segments])
        np.testing.assert_allclose(gaps, want, rtol=0, atol=1e-12)
        # The pair it names is one of the row's, and its gap is the row's.
        np.testing.assert_array_equal(pairs.segment_pair[k], np.arange(len(pairs.segments)))
        i, j = pairs.i[k], pairs.j[k]
        d = np.linalg.norm(c[i] - c[j], axis=-1) - r[i] - r[j]
        np.testing.assert_allclose(d - pairs.allowance[k], want, rtol=0, atol=1e-12)


def test_sphere_distances_match_every_pair(body, pairs, centers):
    r = np.asarray(body.sphere_radii, float)
    for c in centers[:2]:
        got = sphere_distances(
            jnp.asarray(c), body.sphere_radii, jnp.asarray(pairs.i), jnp.asarray(pairs.j)
        )
        want = _distance_matrix(c, r)[pairs.i, pairs.j]
        np.testing.assert_allclose(np.asarray(got), want, rtol=0, atol=1e-12)


def test_environment_gaps_match_a_brute_force_loop(body, centers):
    env = Environment.of(
        planes=[((0.0, 0.0, 1.0), 0.0)],
        spheres=[((0.4, 0.1, 1.0), 0.2)],
        capsules=[((0.3, -0.5, 0.8), (0.3, 0.5, 0.8), 0.05)],
        boxes=[((0.5, 0.0, 0.9), (0.3, 0.4, 0.05), _rot_z(0.3))],
    )
    seg = np.asarray(body.sphere_segment, int)
    c = centers[1]
    gaps_fn = jax.jit(lambda c: environment_gaps(c, body.sphere_radii, env, seg, body.n_segments))
    gaps, k = gaps_fn(jnp.asarray(c))
    gaps, k = np.asarray(gaps), np.asarray(k)
    d = np.asarray(_env_distances(jnp.asarray(c), body.sphere_radii, env))
    for s in range(body.n_segments):
        mine = np.flatnonzero(seg == s)
        if not mine.size:  # the whole body: no spheres, never touches
            assert np.all(np.isposinf(gaps[s]))
            continue
        np.testing.assert_allclose(gaps[s], d[mine].min(0), rtol=0, atol=1e-12)
        assert np.all(seg[k[s]] == s)
        np.testing.assert_allclose(d[k[s], np.arange(env.n_shapes)], gaps[s], atol=1e-12)


# --- references: closed forms -----------------------------------------------------------------
def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


_env_distances = jax.jit(sphere_environment_distances)


def _env_distance(env: Environment, point, radius: float) -> np.ndarray:
    d = _env_distances(jnp.asarray([point], float), jnp.asarray([radius], float), env)
    return np.asarray(d)[0]


@pytest.mark.parametrize(
    ("plane", "point", "radius", "expected"),
    [
        (((0, 0, 1), 0.0), (1.0, 2.0, 0.3), 0.1, 0.2),
        (((0, 0, 2), 1.0), (1.0, 2.0, 0.3), 0.1, -0.3),  # n not unit: the plane z = 0.5
        (((1, 1, 0), 0.0), (1.0, 1.0, 5.0), 0.5, np.sqrt(2) - 0.5),
        (((0, 0, 1), 0.0), (0.0, 0.0, -0.2), 0.1, -0.3),  # below the floor
    ],
)
def test_plane_distance_is_the_closed_form(plane, point, radius, expected):
    env = Environment.of(planes=[plane])
    np.testing.assert_allclose(_env_distance(env, point, radius), [expected], atol=1e-15)


def test_sphere_distance_is_the_closed_form():
    env = Environment.of(spheres=[((1.0, 2.0, 3.0), 0.25)])
    for point, expected in [((1.0, 2.0, 4.0), 0.75 - 0.1), ((4.0, 6.0, 3.0), 5.0 - 0.35)]:
        np.testing.assert_allclose(_env_distance(env, point, 0.1), [expected], atol=1e-15)


@pytest.mark.parametrize(
    ("point", "to_axis"),
    [
        ((0.3, 0.4, 0.5), 0.5),  # beside the middle
        ((0.0, 0.0, 1.3), 0.3),  # beyond end b, on the axis
        ((0.3, 0.0, -0.4), 0.5),  # beyond end a, off the axis
        ((0.6, 0.8, 1.0), 1.0),  # level with end b
    ],
)
def test_capsule_distance_is_the_closed_form(point, to_axis):
    R = _rot_x(0.7) @ _rot_z(-0.4)  # the same capsule turned and moved: the same distance
    shift = np.array([0.1, -0.2, 0.3])
    capsules = [
        ((0, 0, 0), (0, 0, 1), 0.05),
        (tuple(shift), tuple(R @ (0, 0, 1) + shift), 0.05),
    ]
    env = Environment.of(capsules=capsules)
    got = np.asarray(
        _env_distances(jnp.asarray([point, R @ point + shift], float), jnp.asarray([0.1, 0.1]), env)
    )
    want = to_axis - 0.1 - 0.05
    np.testing.assert_allclose([got[0, 0], got[1, 1]], [want, want], atol=1e-14)


@pytest.mark.parametrize(
    ("local", "expected"),
    [
        ((0.5, 0.0, 0.0), 0.4),  # outside a face
        ((0.4, 0.6, 0.0), 0.5),  # beside an edge: (0.3, 0.4) from it
        ((0.2, 0.4, 0.5), 0.3),  # beside a corner: (0.1, 0.2, 0.2) from it
        ((0.1, 0.2, 0.3), 0.0),  # on a corner
        ((0.05, 0.1, 0.0), -0.05),  # inside, nearest the x faces
        ((0.0, 0.05, 0.28), -0.02),  # inside, nearest the top
        ((0.0, 0.0, 0.0), -0.1),  # the centre
    ],
)
def test_box_distance_is_the_closed_form(local, expected):
    centre, half = np.array([1.0, -0.5, 0.2]), (0.1, 0.2, 0.3)
    R = _rot_z(0.5) @ _rot_x(-0.3)
    env = Environment.of(boxes=[(centre, half), (centre, half, R)])
    got = np.asarray(
        _env_distances(
            jnp.asarray([centre + np.asarray(local), centre + R @ np.asarray(local)]),
            jnp.asarray([0.05, 0.05]),
            env,
        )
    )
    np.testing.assert_allclose([got[0, 0], got[1, 1]], [expected - 0.05] * 2, atol=1e-14)


def test_columns_follow_the_shape_names():
    env = Environment.of(
        planes=[((0, 0, 1), 0.0)],
        spheres=[((0, 0, 5), 1.0)],
        capsules=[((3, 0, 0), (3, 0, 1), 0.5)],
        boxes=[((0, 3, 0), (0.5, 0.5, 0.5)), ((9, 9, 9), (1, 1, 1))],
    )
    assert env.shape_names() == ("plane 0", "sphere 0", "capsule 0", "box 0", "box 1")
    want = [1, 3, 2.5, np.sqrt(6.5), np.sqrt(2 * 8**2 + 7**2)]
    np.testing.assert_allclose(_env_distance(env, (0, 0, 1), 0.0), want)


# --- contact report ---------------------------------------------------------------------------
def test_report_of_the_standard_position_is_its_rest_overlaps(body):
    report = contact_report(body, body.rest_pose())
    assert report.contacts  # the arms sit in the torso at rest
    assert max(abs(c.excess) for c in report.contacts) < 1e-9
    assert report.deeper_than_rest() == ()


def test_report_lists_a_hand_moved_into_the_torso(body, pairs):
    rest = body.rest_pose()
    upper, fore = body.segment_index("left_upper_arm"), body.segment_index("left_forearm")
    swing = np.array(db.swing_vector(body, rest.angles))
    swing[fore] = (0.0, 1.6)  # elbow flexed
    twist = np.array(rest.angles[:, 2])
    twist[upper] = 1.2  # arm turned in: the hand goes into the belly
    angles = jax.jit(db.angles_from_swing)(body, jnp.asarray(swing), jnp.asarray(twist))
    pose = db.Pose(rest.position, angles)
    assert bool(jnp.all(jax.jit(db.within_limits)(body, pose)))
    report = contact_report(body, pose)
    deeper = {(c.a, c.b): c for c in report.deeper_than_rest()}
    assert ("L3", "left_hand") in deeper
    # Its excess is the largest over the pair's spheres (what no_contact measures).
    c = np.asarray(jax.jit(db.forward)(body, pose).sphere_centers)
    r = np.asarray(body.sphere_radii)
    row = [tuple(s) for s in pairs.segments.tolist()].index(
        (body.segment_index("L3"), body.segment_index("left_hand"))
    )
    k = np.flatnonzero(pairs.segment_pair == row)
    d = np.linalg.norm(c[pairs.i[k]] - c[pairs.j[k]], axis=-1) - r[pairs.i[k]] - r[pairs.j[k]]
    excess = np.maximum(-d, 0) - np.maximum(-pairs.rest[k], 0)
    assert deeper[("L3", "left_hand")].excess == pytest.approx(excess.max(), abs=1e-12)
    assert excess.max() > 0.02
    assert report.contacts[0].excess == max(c.excess for c in report.contacts)


# --- derivatives ------------------------------------------------------------------------------
def _check_derivatives(f, x: np.ndarray, n_directions: int = 3, h: float = 1e-7):
    """jacfwd == jacrev, and both give central differences along random unit directions
    (steps of h m: small, so that no row's closest pair changes within them)."""
    x = jnp.asarray(x, float)
    f = jax.jit(f)
    jf, jr = jax.jit(jax.jacfwd(f))(x), jax.jit(jax.jacrev(f))(x)
    assert np.all(np.isfinite(np.asarray(jf)))
    np.testing.assert_allclose(np.asarray(jf), np.asarray(jr), rtol=0, atol=1e-12)
    rng = np.random.default_rng(3)
    for _ in range(n_directions):
        v = rng.normal(size=x.shape)
        v = jnp.asarray(v / np.linalg.norm(v))
        fd = (f(x + h * v) - f(x - h * v)) / (2 * h)
        jv = jnp.tensordot(jf, v, axes=v.ndim)
        np.testing.assert_allclose(np.asarray(jv), np.asarray(fd), rtol=0, atol=1e-7)
    return np.asarray(jf)


def test_pair_gap_derivatives_on_the_body(body, pairs, centers):
    f = jax.jit(lambda c: _gaps(c, body.sphere_radii, pairs)[0])
    _check_derivatives(f, centers[2])


# Three spheres: 0 and 1 touch (gap 0), 2 is apart; rows (0-1, 0-2) and (1-2).
TOUCHING = np.array([[0.0, 0.0, 0.0], [0.25, 0.0, 0.0], [0.0, 1.0, 0.0]])
RADII = jnp.asarray([0.1, 0.15, 0.2])
PAIR_I, PAIR_J = jnp.asarray([0, 0, 1]), jnp.asarray([1, 2, 2])
GROUP = np.array([0, 0, 1])


@jax.jit
def _small_gaps(c, allowance=jnp.zeros(3)):
    return closest_pair_gaps(c, RADII, PAIR_I, PAIR_J, allowance, GROUP, 2)[0]


def test_pair_gap_derivatives_at_touching_contact():
    assert float(_small_gaps(jnp.asarray(TOUCHING))[0]) == pytest.approx(0.0, abs=1e-15)
    J = _check_derivatives(_small_gaps, TOUCHING)
    # The touching row moves with the normal: -x for sphere 0, +x for sphere 1.
    np.testing.assert_allclose(J[0], [[-1, 0, 0], [1, 0, 0], [0, 0, 0]], atol=1e-14)
    # An allowance shifts the row, not its derivatives.
    J2 = _check_derivatives(lambda c: _small_gaps(c, jnp.asarray([-0.01, 0, 0])), TOUCHING)
    np.testing.assert_allclose(J2, J, atol=1e-14)


def test_pair_gap_gradients_are_finite_at_coincident_centres():
    c = jnp.asarray(TOUCHING).at[1].set(TOUCHING[0])
    gap = _small_gaps(c)
    assert float(gap[0]) == pytest.approx(-0.25)
    J = np.asarray(jax.jit(jax.jacrev(_small_gaps))(c))
    assert np.all(np.isfinite(J))
    np.testing.assert_array_equal(J[0], 0.0)
    J_fwd = np.asarray(jax.jit(jax.jacfwd(_small_gaps))(c))
    np.testing.assert_allclose(J_fwd, J, rtol=0, atol=1e-15)


# An environment and a sphere (r = 0.1) touching each shape in turn: the floor, a sphere,
# a capsule's side, a box's face; and one point inside each.
ENV = Environment.of(
    planes=[((0, 0, 1), 0.0)],
    spheres=[((0.0, 2.0, 1.0), 0.3)],
    capsules=[((2.0, 0.0, 0.5), (2.0, 0.0, 1.5), 0.05)],
    boxes=[((-2.0, 0.0, 1.0), (0.2, 0.3, 0.4), _rot_z(0.4))],
)
BOX_R = _rot_z(0.4)
TOUCH_POINTS = np.array(
    [
        [0.3, -0.2, 0.1],  # on the floor
        [0.0, 2.0, 1.4],  # on top of the sphere
        [2.15, 0.0, 1.0],  # against the capsule's side
        (np.array([-2.0, 0.0, 1.0]) + BOX_R @ [0.3, 0.1, -0.1]),  # against the box's +x face
    ]
)
SEGMENTS = np.arange(4)


@jax.jit
def _env_gaps(c):
    return environment_gaps(c, jnp.full(4, 0.1), ENV, SEGMENTS, 4)[0]


def test_environment_gap_derivatives_at_touching_contact():
    gaps = np.asarray(_env_gaps(jnp.asarray(TOUCH_POINTS)))
    np.testing.assert_allclose(np.diagonal(gaps), 0.0, atol=1e-15)
    J = _check_derivatives(_env_gaps, TOUCH_POINTS)
    # Each touching row moves with the shape's outward normal, only with its own sphere.
    normals = [[0, 0, 1], [0, 0, 1], [1, 0, 0], BOX_R @ [1, 0, 0]]
    for s, n in enumerate(normals):
        np.testing.assert_allclose(J[s, s, s], n, atol=1e-12)
        assert np.all(np.delete(J[s], s, axis=1) == 0.0)


def test_environment_gap_derivatives_inside_and_at_the_corners():
    c = np.array(
        [
            [0.3, -0.2, -0.5],  # under the floor
            [0.1, 1.9, 1.05],  # inside the sphere
            [2.3, 0.2, 1.9],  # beyond the capsule's end
            (np.array([-2.0, 0.0, 1.0]) + BOX_R @ [0.25, 0.35, 0.5]),  # beyond a corner
        ]
    )
    _check_derivatives(_env_gaps, c)
    inside = c.copy()
    inside[3] = np.array([-2.0, 0.0, 1.0]) + BOX_R @ [0.15, 0.05, 0.0]  # nearest the +x face
    J = _check_derivatives(_env_gaps, inside)
    np.testing.assert_allclose(J[3, 3, 3], BOX_R @ [1, 0, 0], atol=1e-12)


def test_environment_gradients_are_finite_at_the_shapes_centres():
    c = jnp.asarray(
        [
            [0.0, 0.0, 0.0],  # on the floor plane itself
            [0.0, 2.0, 1.0],  # the sphere's centre
            [2.0, 0.0, 1.0],  # on the capsule's axis
            [-2.0, 0.0, 1.0],  # the box's centre
        ]
    )
    J = np.asarray(jax.jit(jax.jacrev(_env_gaps))(c))
    assert np.all(np.isfinite(J))
    assert np.all(np.isfinite(np.asarray(jax.jit(jax.jacfwd(_env_gaps))(c))))
    np.testing.assert_allclose(np.diagonal(np.asarray(_env_gaps(c))), [-0.1, -0.4, -0.15, -0.3])


# --- properties -------------------------------------------------------------------------------
coordinate = st.floats(-2.0, 2.0, allow_nan=False)
point = st.tuples(coordinate, coordinate, coordinate)
angle = st.floats(-np.pi, np.pi, allow_nan=False)


def _rotation(a: float, b: float, c: float) -> np.ndarray:
    return _rot_z(a) @ _rot_x(b) @ _rot_z(c)


@settings(max_examples=20)
@given(
    p=point,
    q=point,
    ra=st.floats(0.0, 0.5),
    rb=st.floats(0.0, 0.5),
    turn=st.tuples(*[angle] * 3),
    shift=point,
)
def test_pair_distances_are_symmetric_and_rigid_motion_invariant(p, q, ra, rb, turn, shift):
    c = np.array([p, q])
    r = jnp.asarray([ra, rb])
    moved = c @ _rotation(*turn).T + np.asarray(shift)
    d = [
        float(sphere_distances(jnp.asarray(x), r, jnp.asarray([i]), jnp.asarray([j]))[0])
        for x in (c, moved)
        for i, j in ((0, 1), (1, 0))
    ]
    np.testing.assert_allclose(d, d[0], rtol=0, atol=1e-12)
    assert d[0] == pytest.approx(np.linalg.norm(c[0] - c[1]) - ra - rb, abs=1e-12)


@settings(max_examples=20)
@given(p=point, half=st.tuples(*[st.floats(0.01, 1.0)] * 3), turn=st.tuples(*[angle] * 3))
def test_box_distance_lies_between_its_inner_and_outer_balls(p, half, turn):
    """A signed distance grows as the solid shrinks: the ball inscribed in a box is inside it,
    and the box inside its circumscribed ball."""
    centre = np.array([0.1, -0.2, 0.3])
    env = Environment.of(
        boxes=[(centre, half, _rotation(*turn))],
        spheres=[(centre, min(half)), (centre, float(np.linalg.norm(half)))],
    )
    inner, outer, box = _env_distance(env, p, 0.05)
    assert outer - 1e-12 <= box <= inner + 1e-12


@settings(max_examples=20)
@given(p=point, q=point)
def test_distances_to_every_shape_are_1_lipschitz(p, q):
    """|d(p) - d(q)| <= |p - q|: a signed distance changes no faster than the point moves."""
    env = Environment.of(
        planes=[((0.3, -0.4, 1.0), 0.2)],
        spheres=[((0.5, 0.5, 0.5), 0.4)],
        capsules=[((-1.0, 0.0, 0.0), (0.5, 1.0, -0.5), 0.2)],
        boxes=[((0.0, -1.0, 0.5), (0.3, 0.5, 0.2), _rotation(0.3, 1.1, -0.7))],
    )
    dp, dq = _env_distance(env, p, 0.1), _env_distance(env, q, 0.1)
    assert np.all(np.abs(dp - dq) <= np.linalg.norm(np.subtract(p, q)) + 1e-12)


# --- which pairs are checked ------------------------------------------------------------------
def _checked(body, pairs) -> set[tuple[str, str]]:
    names = body.segment_names
    return {(names[a], names[b]) for a, b in pairs.segments}


def test_no_checked_pair_is_parent_and_child(body, pairs):
    for a, b in pairs.segments:
        assert body.parent[a] != b and body.parent[b] != a
    assert np.all(pairs.i < pairs.j)
    seg = np.asarray(body.sphere_segment)
    assert np.all(seg[pairs.i] != seg[pairs.j])


def test_the_rigid_pelvis_and_the_trunk_are_not_checked(body, pairs):
    names = body.segment_names
    pelvis = ("whole_body", "pelvis", "left_pelvis", "right_pelvis")
    group = rigid_groups(body)
    assert len({group[body.segment_index(n)] for n in pelvis}) == 1
    trunk = (*pelvis, *body.spine.segment_names)
    checked = _checked(body, pairs)
    skip = {(names[a], names[b]) for a, b in excluded_segment_pairs(body)}
    for a, b in itertools.combinations(trunk, 2):
        assert (a, b) not in checked and (b, a) not in checked
        assert (a, b) in skip or (b, a) in skip
    # A thigh meets the pelvis at its hip, the clavicles and the neck at T1's distal joint.
    for a, b in [("pelvis", "left_thigh"), ("left_pelvis", "left_thigh"),
                 ("right_pelvis", "left_thigh"), ("left_clavicle", "right_clavicle"),
                 ("neck", "left_clavicle"), ("T1", "left_clavicle")]:  # fmt: skip
        assert (a, b) not in checked and (b, a) not in checked


def test_limbs_are_checked_against_each_other_and_the_trunk(body, pairs):
    checked = _checked(body, pairs)
    for pair in [
        ("left_thigh", "right_thigh"),
        ("left_shank", "right_shank"),
        ("L3", "left_hand"),
        ("pelvis", "left_hand"),
        ("left_thigh", "left_hand"),
        ("head", "right_hand"),
        ("left_hand", "right_hand"),
        ("T6", "left_upper_arm"),
    ]:
        assert pair in checked or pair[::-1] in checked, pair


def test_pairs_of_named_segments_are_a_subset(body, pairs):
    hand = sphere_pairs(body, ["left_hand"])
    k = body.segment_index("left_hand")
    seg = np.asarray(body.sphere_segment)
    assert np.all((seg[hand.i] == k) | (seg[hand.j] == k))
    full = set(zip(pairs.i.tolist(), pairs.j.tolist()))
    mine = set(zip(hand.i.tolist(), hand.j.tolist()))
    assert mine < full
    assert mine == {(i, j) for i, j in full if k in (seg[i], seg[j])}
