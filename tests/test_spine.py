"""Bendspine and Movespine (seed 004): properties from the paper, derivatives, the body.

The paper's properties hold for a chain of any length: they run on the shipped 17-vertebra
spine and on chains of 5 and 9 joints built from its data alone (`bodies.lumped_spine_doc`);
the body's, the files' and the arguments' tests on the shipped spine."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from bodies import lumped_spine_doc, write
from hypothesis import event, given, settings
from hypothesis import strategies as st

import diffbody as db
from diffbody.files._data_files import data_file

DEG = np.pi / 180
# The seed's six figure targets (flexion, axial, lateral) in degrees, mapped one to one onto
# ours (flexion forward about Y, axial to the left about Z, lateral to the right about X).
FIGURES = [
    (-52, 58, -7),
    (-1, -60, -6),
    (3, -42, 23),
    (-10, 108, -45),
    (18, 108, -68),
    (-33, 39, 6),
]


@pytest.fixture(scope="module")
def spine():
    return db.load_spine()


@pytest.fixture(scope="module", params=[None, 5, 9], ids=["T1-L5", "5 joints", "9 joints"])
def chain(request, spine, tmp_path_factory):
    """The shipped spine, and chains of 5 and 9 joints read from files built from its data
    (no code change: the database takes any number of joints)."""
    if request.param is None:
        return spine
    folder = tmp_path_factory.mktemp("spines")
    chain = db.load_spine(write(lumped_spine_doc(request.param), folder / "spine.json"))
    assert chain.n_joints == request.param
    return chain


@pytest.fixture(scope="module")
def bend(chain):
    """bendspine on `chain`, compiled once per zero-interpolation flag; every other input
    traced. The initiator defaults to joint 9 of the shipped spine (`_at`)."""
    fns = {
        z: jax.jit(
            lambda c, t, i, r, res, rng, z=z: db.bendspine(
                chain,
                c,
                t,
                initiator=i,
                resistor=r,
                resistance=res,
                joint_range=rng,
                zero_interpolation=z,
            )
        )
        for z in (True, False)
    }

    def call(
        current,
        target,
        initiator=None,
        resistor=None,
        resistance=0.0,
        joint_range=None,
        zero_interpolation=True,
    ):
        n = chain.n_joints
        initiator = _at(9, chain) if initiator is None else initiator
        resistor = initiator if resistor is None else resistor
        rng = (0, n - 1) if joint_range is None else joint_range
        return fns[zero_interpolation](
            jnp.asarray(current),
            jnp.asarray(target),
            jnp.asarray(initiator),
            jnp.asarray(resistor),
            jnp.asarray(resistance, float),
            jnp.asarray(rng),
        )

    return call


def _state(spine, u):
    """A spine state inside the limits from uniforms in [0, 1] (the first 3 n of them).
    Clipped: lo + (hi - lo) can round one ulp past hi, which bendspine would clip (a frozen
    joint would seem to move)."""
    lo, hi = np.asarray(spine.lower), np.asarray(spine.upper)
    return np.clip(lo + (hi - lo) * np.asarray(u)[: lo.size].reshape(lo.shape), lo, hi)


def _n(spine):
    return spine.n_joints


def _index(f: float, n: int) -> int:
    """A joint index in [0, n) from a uniform f in [0, 1]."""
    return min(int(f * n), n - 1)


def _at(k: int, chain) -> int:
    """The joint of `chain` where joint k of the shipped spine's 18 lies (k itself there)."""
    return round(k / 17 * (chain.n_joints - 1))


unit = st.floats(0.0, 1.0)

# The longest chain the properties draw for: the shipped spine's joints.
N_JOINTS = 18


@st.composite
def problems(draw):
    """A problem for any chain of at most `N_JOINTS` joints, its joint indices as uniforms
    (`_indices` places them on a chain)."""
    u = draw(st.lists(unit, min_size=3 * N_JOINTS, max_size=3 * N_JOINTS))
    where = draw(st.lists(unit, min_size=4, max_size=4))
    resistance = draw(unit)
    frac = draw(st.lists(unit, min_size=3, max_size=3))
    zero = draw(st.booleans())
    return u, where, resistance, frac, zero


def _indices(spine, where) -> tuple[tuple[int, int], int, int]:
    """The joint range, initiator (inside it) and resistor of `problems`' uniforms on
    `spine`."""
    n = spine.n_joints
    lo_j = _index(where[0], n)
    hi_j = lo_j + _index(where[1], n - lo_j)
    init = lo_j + _index(where[2], hi_j - lo_j + 1)
    return (lo_j, hi_j), init, _index(where[3], n)


def _feasible_target(spine, current, rng_, frac):
    """A target within what the active joints can reach, the frozen ones staying."""
    active = np.zeros(spine.n_joints, bool)
    active[rng_[0] : rng_[1] + 1] = True
    lo = np.where(active[:, None], np.asarray(spine.lower), current).sum(0)
    hi = np.where(active[:, None], np.asarray(spine.upper), current).sum(0)
    return lo + (hi - lo) * np.asarray(frac), active


@given(problems())
def test_sum_equals_feasible_target_and_limits_hold(chain, bend, prob):
    u, where, resistance, frac, zero = prob
    rng_, init, res = _indices(chain, where)
    current = _state(chain, u)
    target, active = _feasible_target(chain, current, rng_, frac)
    out = bend(current, target, init, res, resistance, rng_, zero)
    a = np.asarray(out.angles)
    np.testing.assert_allclose(a.sum(0), target, atol=1e-9)
    assert bool(np.all(out.reached))
    assert np.all(a >= np.asarray(chain.lower) - 1e-12) and np.all(
        a <= np.asarray(chain.upper) + 1e-12
    )
    np.testing.assert_array_equal(a[~active], current[~active])  # frozen joints never move


@given(problems())
def test_beyond_the_limits_the_spine_stops_at_them(chain, bend, prob):
    u, where, resistance, frac, zero = prob
    _, init, res = _indices(chain, where)
    current = _state(chain, u)
    lo, hi = np.asarray(chain.lower).sum(0), np.asarray(chain.upper).sum(0)
    target = np.where(np.asarray(frac) > 0.5, hi + 0.3, lo - 0.3)
    out = bend(current, target, init, res, resistance, None, zero)
    assert not np.any(out.reached)
    bound = np.where(np.asarray(frac) > 0.5, np.asarray(chain.upper), np.asarray(chain.lower))
    np.testing.assert_allclose(out.angles, bound, atol=1e-12)
    np.testing.assert_allclose(out.shortfall, target - bound.sum(0), atol=1e-12)


@given(st.lists(unit, min_size=3 * N_JOINTS, max_size=3 * N_JOINTS), unit, st.booleans())
def test_full_participation_puts_every_joint_at_its_limit(chain, bend, u, init, up):
    current = _state(chain, u)
    bound = np.asarray(chain.upper if up else chain.lower)
    out = bend(current, bound.sum(0), _index(init, _n(chain)))
    np.testing.assert_allclose(out.angles, bound, atol=1e-9)


@given(problems(), unit, unit)
def test_more_resistance_never_moves_the_resistive_region_more(chain, bend, prob, r1, r2):
    """With zero interpolation a move across the rest posture first returns every joint to
    rest, resistance or not (the seed interpolates through it); so there we start at rest."""
    u, where, _, frac, zero = prob
    _, init, res = _indices(chain, where)
    if res == init:
        return
    current = np.asarray(chain.rest) if zero else _state(chain, u)
    target, _ = _feasible_target(chain, current, (0, _n(chain) - 1), frac)
    lo_r, hi_r = sorted((r1, r2))
    region = np.arange(_n(chain))
    region = region >= res if res > init else region <= res
    moved = [
        np.abs(np.asarray(bend(current, target, init, res, r, None, zero).angles) - current)[
            region
        ].sum(0)
        for r in (lo_r, hi_r)
    ]
    assert np.all(moved[1] <= moved[0] + 1e-9)


def test_full_resistance_keeps_the_resistive_region_until_the_active_one_is_spent(chain, bend):
    """A lumbar initiator (on the shipped spine joint 16, L4-L5), the resistor above it
    (joint 10, T10-T11): the thorax resists."""
    rest = np.asarray(chain.rest)
    hi = np.asarray(chain.upper)
    init, res = _at(16, chain), _at(10, chain)
    active_room = (hi - rest)[res + 1 :].sum(0)
    small = rest.sum(0) + 0.9 * active_room
    out = np.asarray(bend(rest, small, init, res, 1.0).angles)
    np.testing.assert_allclose(out[: res + 1], rest[: res + 1], atol=1e-12)
    big = rest.sum(0) + active_room + 0.05
    out = np.asarray(bend(rest, big, init, res, 1.0).angles)
    np.testing.assert_allclose(out[res + 1 :], hi[res + 1 :], atol=1e-12)
    assert np.all(np.abs(out[: res + 1] - rest[: res + 1]).sum(0) > 0.01)


@pytest.mark.parametrize("where", [2, 6, 9, 13, 16])
@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_initiator_moves_most_on_a_fresh_bend(chain, spine, bend, where, axis, sign):
    """A small bend (a tenth of the room): the initiator takes the largest share of its
    room, w_i = p_i (bound_i - j_i) with p_i largest there, and the share falls off with
    distance, on any chain. On the shipped spine, whose neighbouring joints have similar
    rooms, it also moves most; on a chain of lumped joints a joint with five times the
    initiator's room can move more (the global participation P spreads by room)."""
    n = _n(chain)
    init = _at(where, chain)
    rest = np.asarray(chain.rest)
    room = np.asarray(chain.upper if sign > 0 else chain.lower)[:, axis] - rest[:, axis]
    target = rest.sum(0).copy()
    target[axis] += 0.1 * room.sum()
    moved = np.abs(np.asarray(bend(rest, target, init).angles)[:, axis] - rest[:, axis])
    share = moved / np.abs(room)
    assert np.argmax(share) == init
    nearby = [k for k in (init - 4, init + 4) if 0 <= k < n]
    assert all(share[k] < share[init] for k in nearby)
    if chain is spine:
        assert np.argmax(moved) == init
        assert all(moved[k] < moved[init] for k in nearby)


def test_zero_interpolation_goes_through_the_rest_posture(chain, bend):
    """Yes: crossing the rest posture, every joint is at rest when the sum is the rest sum.
    No: only the limits are interpolated toward, so returning takes another path."""
    rest = np.asarray(chain.rest)
    top, low = _at(4, chain), _at(14, chain)
    flexed = np.asarray(bend(rest, rest.sum(0) + np.array([0.5, 0, 0]), top).angles)
    back = [
        np.asarray(bend(flexed, rest.sum(0), low, zero_interpolation=z).angles)
        for z in (True, False)
    ]
    np.testing.assert_allclose(back[0], rest, atol=1e-12)
    assert np.abs(back[1] - rest).max() > 1e-3
    np.testing.assert_allclose(back[1].sum(0), rest.sum(0), atol=1e-9)
    # Past the rest posture, "yes" starts from rest: the result does not remember the flexion.
    ext = rest.sum(0) - np.array([0.3, 0, 0])
    np.testing.assert_allclose(
        bend(flexed, ext, low).angles, bend(rest, ext, low).angles, atol=1e-12
    )


def test_gradient_with_respect_to_the_target(chain):
    rest = jnp.asarray(chain.rest)
    f = jax.jit(lambda t: db.bendspine(chain, rest, t, initiator=_at(9, chain)).angles)
    t0 = rest.sum(0) + jnp.array([0.2, -0.15, 0.1])
    jf, jr = jax.jacfwd(f)(t0), jax.jacrev(f)(t0)
    np.testing.assert_allclose(jf, jr, atol=1e-12)
    h = 1e-6
    fd = np.stack([(f(t0 + h * e) - f(t0 - h * e)) / (2 * h) for e in np.eye(3)], -1)
    np.testing.assert_allclose(fd, jf, atol=1e-6)
    assert np.all(np.isfinite(jax.jacfwd(f)(rest.sum(0))))  # at rest: zero movement


def test_vmap_equals_a_loop(chain, bend):
    rng = np.random.default_rng(0)
    n = _n(chain)
    currents = np.stack([_state(chain, rng.uniform(size=3 * n)) for _ in range(4)])
    targets = np.stack(
        [_feasible_target(chain, c, (0, n - 1), rng.uniform(size=3))[0] for c in currents]
    )
    init = _at(5, chain)
    batched = jax.jit(jax.vmap(lambda c, t: db.bendspine(chain, c, t, initiator=init).angles))(
        currents, targets
    )
    for k in range(4):
        np.testing.assert_allclose(
            batched[k], bend(currents[k], targets[k], init).angles, atol=1e-13
        )


@pytest.mark.parametrize("figure", FIGURES)
def test_the_seeds_figure_targets(chain, bend, figure):
    target = np.asarray(figure) * DEG
    out = bend(np.asarray(chain.rest), target, _at(12, chain))
    lo, hi = np.asarray(chain.lower).sum(0), np.asarray(chain.upper).sum(0)
    feasible = (target >= lo) & (target <= hi)
    np.testing.assert_array_equal(np.asarray(out.reached), feasible)
    a = np.asarray(out.angles)
    np.testing.assert_allclose(a.sum(0)[feasible], target[feasible], atol=1e-9)
    nearest = np.clip(target, lo, hi)
    np.testing.assert_allclose(a.sum(0), nearest, atol=1e-9)


def test_movespine_scans_a_sequence(chain, bend):
    rest = np.asarray(chain.rest)
    n = _n(chain)
    init = _at(8, chain)
    t = np.linspace(0, 1, 9)
    targets = rest.sum(0) + np.stack(
        [0.4 * np.sin(2 * np.pi * t), 0 * t, 0.2 * np.sin(4 * np.pi * t)], -1
    )
    out = db.movespine(chain, rest, targets, initiator=init, zero_interpolation=False)
    assert out.angles.shape == (9, n, 3)
    np.testing.assert_allclose(out.angles.sum(1), targets, atol=1e-9)
    prev = rest
    for k in range(9):  # each step starts where the last ended
        np.testing.assert_allclose(
            out.angles[k],
            bend(prev, targets[k], init, zero_interpolation=False).angles,
            atol=1e-12,
        )
        prev = np.asarray(out.angles[k])


def test_the_body_follows_the_spine(male50, spine):
    pose = male50.rest_pose()
    np.testing.assert_allclose(db.spine_angles(male50, spine, pose), spine.rest, atol=1e-12)
    bent, out = db.bend_pose(
        male50, spine, pose, spine.rest.sum(0) + jnp.array([0.6, 0.3, -0.2]), initiator=12
    )
    np.testing.assert_allclose(db.spine_angles(male50, spine, bent), out.angles, atol=1e-12)
    assert bool(jnp.all(db.within_limits(male50, bent, tol=1e-9)))
    fk0, fk1 = db.forward(male50, pose), db.forward(male50, bent)
    head = male50.feature_index("head.top")
    # Flexion brings the head forward and down; torso spheres move with the vertebrae.
    assert fk1.feature_points[head][0] > fk0.feature_points[head][0] + 0.1
    assert fk1.feature_points[head][2] < fk0.feature_points[head][2] - 0.02
    t7 = male50.segment_spheres("T7")
    assert float(jnp.abs(fk1.sphere_centers[t7] - fk0.sphere_centers[t7]).max()) > 0.02


def test_the_database_agrees_with_the_body(male50, spine):
    """The body's vertebra limits are the spine's limits less its rest angles (the standard
    position is the spine at rest)."""
    seg = np.asarray([male50.segment_index(s) for s in spine.segment_names])
    dev_lo = np.asarray(spine.lower - spine.rest)
    dev_hi = np.asarray(spine.upper - spine.rest)
    np.testing.assert_allclose(np.asarray(male50.swing_lo)[seg], dev_lo[:, [2, 0]], atol=1e-9)
    np.testing.assert_allclose(np.asarray(male50.swing_hi)[seg], dev_hi[:, [2, 0]], atol=1e-9)
    np.testing.assert_allclose(np.asarray(male50.twist_lo)[seg], dev_lo[:, 1], atol=1e-9)
    np.testing.assert_allclose(np.asarray(male50.twist_hi)[seg], dev_hi[:, 1], atol=1e-9)
    rest_flex = np.degrees(np.asarray(spine.rest)[:, 0])
    assert abs(rest_flex[1:12].sum() - 40) < 1e-6 and abs(rest_flex[13:].sum() + 60) < 1e-6


def test_bad_spine_file_is_named(tmp_path):
    import json

    doc = json.loads(data_file("spine.json").read_text())
    doc["joints"][3]["rest_deg"][0] = 90.0
    path = tmp_path / "spine.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(
        db.BodyFileError,
        match=r"spine.json: joint 'T3_T4' \(joints\[3\]\), field 'rest_deg'",
    ):
        db.load_spine(path)
    del doc["joints"][2]["limits_deg"]
    path.write_text(json.dumps(doc))
    with pytest.raises(db.BodyFileError, match="joint 'T2_T3'"):
        db.load_spine(path)


def test_bad_arguments_are_rejected(spine):
    with pytest.raises(
        ValueError, match=r"initiator must be an integer joint index in \[0, 17\], got 18"
    ):
        db.bendspine(spine, spine.rest, jnp.zeros(3), initiator=18)
    with pytest.raises(ValueError, match=r"initiator must lie in joint_range \[5, 9\], got 2"):
        db.bendspine(spine, spine.rest, jnp.zeros(3), initiator=2, joint_range=(5, 9))
    with pytest.raises(KeyError, match="T6_T7"):
        spine.joint_index("T6-T7")


def test_a_pose_can_carry_a_spine_target(male50):
    spine = male50.spine
    rest = male50.rest_pose()
    target = spine.rest.sum(0) + jnp.array([0.5, 0.2, -0.1])
    carried = db.Pose(rest.position, rest.angles, spine_target=target)
    bent, _ = db.bend_pose(male50, spine, rest, target, initiator=spine.initiator)
    fk = jax.jit(db.forward)
    np.testing.assert_allclose(
        fk(male50, carried).sphere_centers, fk(male50, bent).sphere_centers, atol=1e-12
    )
    # Differentiable in the target (away from the clamps): the top of the head.
    top = male50.feature_index("head.top")

    def head(t):
        return db.forward(
            male50, db.Pose(rest.position, rest.angles, spine_target=t)
        ).feature_points[top]

    jac = jax.jit(jax.jacfwd(head))(target)
    np.testing.assert_allclose(jac, jax.jit(jax.jacrev(head))(target), atol=1e-12)
    h = 1e-6
    fd = np.stack([(head(target + h * e) - head(target - h * e)) / (2 * h) for e in np.eye(3)], -1)
    np.testing.assert_allclose(fd, jac, atol=1e-6)
    # Batches of targets are a vmap.
    targets = jnp.stack([target, spine.rest.sum(0)])
    batch = jax.jit(
        jax.vmap(lambda t: db.forward(male50, db.Pose(rest.position, rest.angles, spine_target=t)))
    )
    np.testing.assert_allclose(
        batch(targets).sphere_centers[1], fk(male50, rest).sphere_centers, atol=1e-12
    )


def test_a_spine_target_traces_no_host_callback(male50):
    """Regression: `forward` bent the spine through the checked `bendspine`, whose traced
    checks are host callbacks; XLA keeps no program with one in its persistent cache, so
    every solve with the spine (the sphere-cloud fit, whole-body reach) compiled anew in
    every process. The body is traced here as in the solvers."""
    rest = male50.rest_pose()
    carried = db.Pose(rest.position, rest.angles, spine_target=male50.spine.rest.sum(0))
    text = jax.jit(db.forward).lower(male50, carried).as_text()
    assert "callback" not in text


def test_spine_target_needs_a_spine(tmp_path):
    from bodies import mini_doc, write

    body = db.load_body(write(mini_doc(), tmp_path / "mini.json"))
    pose = body.rest_pose()
    with pytest.raises(ValueError, match="no spine database"):
        db.forward(body, db.Pose(pose.position, pose.angles, spine_target=jnp.zeros(3)))
    doc = mini_doc()
    doc["spine"] = str(data_file("spine.json"))
    with pytest.raises(db.BodyFileError, match="'spine'.*moves segment 'neck'"):
        db.load_body(write(doc, tmp_path / "mini_spine.json"))


# --- arguments out of range, non-finite targets -----------------------------------------------

NAN, INF = float("nan"), float("inf")


# (argument named in the message, bendspine keyword arguments); resistor=3 so that resistance
# is in use.
BAD_ARGUMENTS = [
    *[("resistance", dict(resistor=3, resistance=v)) for v in (1.5, -0.2, NAN, INF)],
    *[("spread", dict(spread=v)) for v in (0, -1, NAN)],
    *[
        (name, {name: v})
        for name in ("initiator", "resistor")
        for v in (18, -1, 5.5, 5.0, True, np.array([40]), np.arange(2))
    ],
    *[("joint_range", dict(joint_range=v)) for v in ((5, 2), (0, 18), (0.5, 3), (-1, 4))],
    ("initiator", dict(initiator=2, joint_range=(5, 9))),
    *[("tol", dict(tol=v)) for v in (0, -1, NAN)],
    ("current", dict(current="short")),
    ("current", dict(current="nan")),
    ("target", dict(target=np.zeros(2))),
    ("zero_interpolation", dict(zero_interpolation=1)),
]


def _bad_call(spine, kwargs):
    kwargs = dict(kwargs)
    current = np.asarray(spine.rest).copy()
    if kwargs.get("current") == "short":
        current = current[:17]
    elif kwargs.get("current") == "nan":
        current[3, 1] = NAN
    kwargs.pop("current", None)
    target = kwargs.pop("target", np.asarray(spine.rest).sum(0))
    kwargs.setdefault("initiator", 9)
    return db.bendspine(spine, current, target, **kwargs)


@pytest.mark.parametrize(("name", "kwargs"), BAD_ARGUMENTS, ids=lambda x: repr(x)[:40])
def test_every_argument_out_of_range_is_named(spine, name, kwargs):
    with pytest.raises(ValueError, match=f"^bendspine: {name} must"):
        _bad_call(spine, kwargs)


def test_integer_scalars_of_any_kind_are_joint_indices(spine):
    rest = spine.rest
    ref = db.bendspine(spine, rest, rest.sum(0) + 0.1, initiator=4, resistor=8, resistance=0.5)
    for i, r in ((np.int64(4), np.int32(8)), (jnp.int32(4), jnp.asarray(8)), (np.array(4), 8)):
        out = db.bendspine(spine, rest, rest.sum(0) + 0.1, initiator=i, resistor=r, resistance=0.5)
        np.testing.assert_array_equal(out.angles, ref.angles)


def test_eager_calls_compile_once(spine):
    """The checks run on the host and the kernel is compiled once: Python, numpy and jax
    scalars of the arguments all reach it as the same arrays."""
    from diffbody._spine import _bend_kernel

    kernel = _bend_kernel if hasattr(_bend_kernel, "_cache_size") else _bend_kernel.__wrapped__
    rest = spine.rest
    db.bendspine(spine, rest, rest.sum(0), initiator=9)
    before = kernel._cache_size()
    for kw in (
        dict(initiator=np.int64(4), resistor=3, resistance=0.5),
        dict(initiator=jnp.int32(2), joint_range=(0, 5), zero_interpolation=False),
        dict(initiator=12, spread=2, tol=1e-6, joint_range=np.array([10, 17])),
    ):
        db.bendspine(spine, np.asarray(rest), np.asarray(rest).sum(0) + 0.2, **kw)
    assert kernel._cache_size() == before


@pytest.mark.parametrize(
    ("name", "kwargs"),
    [
        ("initiator", dict(initiator=[1, 2, 30])),
        ("initiator", dict(initiator=1.0)),
        ("resistance", dict(resistor=3, resistance=[0.0, 1.5, 0.0])),
        ("resistance", dict(resistor=3, resistance=[0.0, 0.5])),
        ("joint_range", dict(joint_range=[(0, 17), (5, 2), (0, 17)])),
        ("initiator", dict(initiator=[1, 2, 9], joint_range=[(0, 17), (0, 17), (10, 17)])),
        ("spread", dict(spread=0.0)),
        ("targets", dict(targets=np.zeros(3))),
    ],
    ids=lambda x: repr(x)[:40],
)
def test_movespine_checks_every_step(spine, name, kwargs):
    kwargs = dict(kwargs)
    targets = kwargs.pop("targets", np.tile(np.asarray(spine.rest).sum(0), (3, 1)))
    kwargs = {k: np.asarray(v) if isinstance(v, list) else v for k, v in kwargs.items()}
    kwargs.setdefault("initiator", 9)
    with pytest.raises(ValueError, match=f"^movespine: {name} must"):
        db.movespine(spine, spine.rest, targets, **kwargs)


# A failed eqx.error_if under jax.jit raises jax's JaxRuntimeError (a RuntimeError) or, with
# some dispatch orders, a ValueError; both carry the check's message.
RUNTIME_ERRORS = (RuntimeError, ValueError)


@pytest.fixture(scope="module")
def traced_bend(spine):
    """bendspine with every checked argument traced, compiled once."""

    @jax.jit
    def f(c, t, i, r, res, rng, spread, tol):
        out = db.bendspine(
            spine, c, t, initiator=i, resistor=r, resistance=res, joint_range=rng,
            spread=spread, tol=tol,
        )  # fmt: skip
        return out.angles  # `reached` alone depends on tol: its check must still run

    def call(**kw):
        rest = np.asarray(spine.rest)
        a = dict(c=rest, t=rest.sum(0), i=9, r=3, res=0.5, rng=(0, 17), spread=3.0, tol=1e-9)
        a.update(kw)
        ints = ("i", "r", "rng")
        return f(**{k: jnp.asarray(v, int if k in ints else float) for k, v in a.items()})

    return call


@pytest.mark.parametrize(
    ("name", "kw"),
    [
        ("resistance", dict(res=1.5)),
        ("resistance", dict(res=NAN)),
        ("initiator", dict(i=40)),
        ("initiator", dict(i=-1)),
        ("resistor", dict(r=18)),
        ("joint_range", dict(rng=(5, 2))),
        ("initiator", dict(i=2, rng=(5, 9))),
        ("spread", dict(spread=0.0)),
        ("tol", dict(tol=-1.0)),
        ("current", dict(c=np.where(np.eye(18, 3) > 0, NAN, 0.0))),
    ],
    ids=lambda x: repr(x)[:30],
)
def test_traced_arguments_are_checked_at_run_time(traced_bend, name, kw):
    assert np.all(np.isfinite(traced_bend()))  # in range, the same function runs
    with pytest.raises(RUNTIME_ERRORS, match=f"bendspine: {name} must"):
        jax.block_until_ready(traced_bend(**kw))


def test_checks_under_vmap_and_movespine_under_jit(spine):
    rest = spine.rest
    bend = jax.vmap(
        lambda res: (
            db.bendspine(spine, rest, rest.sum(0), initiator=9, resistor=3, resistance=res).angles
        )
    )
    assert bend(jnp.array([0.0, 1.0])).shape == (2, 18, 3)
    with pytest.raises(RUNTIME_ERRORS, match="bendspine: resistance must lie in"):
        jax.block_until_ready(bend(jnp.array([0.5, 1.5])))
    move = jax.jit(
        lambda i: db.movespine(spine, rest, jnp.tile(rest.sum(0), (3, 1)), initiator=i).angles
    )
    assert move(jnp.array([1, 2, 3])).shape == (3, 18, 3)
    with pytest.raises(RUNTIME_ERRORS, match="movespine: initiator must be an integer joint index"):
        jax.block_until_ready(move(jnp.array([1, 2, 30])))


@pytest.mark.parametrize("resistance", [0.0, 0.5, 1.0])
def test_non_finite_targets_bend_to_the_limits_and_are_never_reached(spine, resistance):
    """+inf bends to the upper limits, -inf to the lower, as a huge target does; NaN leaves
    the rotation alone. None is reached, and no angle is NaN (with resistance 1, inf times a
    zero weight used to give NaN; inf counted as reached, since inf <= tol * inf)."""
    rest = np.asarray(spine.rest)
    lo, hi = np.asarray(spine.lower), np.asarray(spine.upper)
    kw = dict(initiator=12, resistor=4, resistance=resistance)
    current = rest.copy()
    current[:, 2] += 0.3 * (hi - rest)[:, 2]
    out = db.bendspine(spine, current, np.array([INF, -INF, NAN]), **kw)
    assert not np.any(out.reached)
    a = np.asarray(out.angles)
    assert np.all(np.isfinite(a))
    np.testing.assert_allclose(a[:, 0], hi[:, 0], atol=1e-12)
    np.testing.assert_allclose(a[:, 1], lo[:, 1], atol=1e-12)
    np.testing.assert_array_equal(a[:, 2], current[:, 2])
    assert out.shortfall[0] == INF and out.shortfall[1] == -INF and np.isnan(out.shortfall[2])
    huge = db.bendspine(spine, current, np.array([1e300, -1e300, current[:, 2].sum()]), **kw)
    np.testing.assert_array_equal(np.asarray(huge.angles)[:, :2], a[:, :2])
    assert not np.any(huge.reached[:2]) and bool(huge.reached[2])
    # also compiled, the target traced
    jitted = jax.jit(lambda t: db.bendspine(spine, current, t, **kw))(jnp.array([INF, -INF, NAN]))
    np.testing.assert_allclose(jitted.angles, a, atol=1e-12)
    assert not np.any(jitted.reached)


def test_resistance_above_one_is_rejected(spine):
    """It made r_i negative: weights of both signs, angles far outside the limits, reported
    reached."""
    rest = spine.rest
    with pytest.raises(ValueError, match=r"resistance must lie in \[0, 1\], got 1.5"):
        db.bendspine(spine, rest, rest.sum(0) + 0.3, initiator=12, resistor=4, resistance=1.5)


def test_unbending_with_joints_on_both_sides_of_rest_keeps_the_limits(spine):
    """Axial rotation: the upper joints turned fully left, the lower ones fully right, three
    quarters of the way back to the rest sum. Joints left of rest and right of rest both
    return; the weighted formula alone pushed some past their limits (by 0.05 rad)."""
    rest = np.asarray(spine.rest)
    lo, hi = np.asarray(spine.lower), np.asarray(spine.upper)
    current = rest.copy()
    current[:, 1] = np.where(np.arange(18) < 8, hi[:, 1], lo[:, 1])
    target = current.sum(0)
    target[1] = rest[:, 1].sum() + 0.8 * (current[:, 1].sum() - rest[:, 1].sum())
    for zero in (True, False):
        out = db.bendspine(spine, current, target, initiator=9, zero_interpolation=zero)
        a = np.asarray(out.angles)
        assert np.all(a >= lo - 1e-12) and np.all(a <= hi + 1e-12)
        assert np.all(out.reached)
        np.testing.assert_allclose(a.sum(0), target, atol=1e-9)
    # at the rest sum every joint is back at rest
    target[1] = rest[:, 1].sum()
    out = db.bendspine(spine, current, target, initiator=9)
    np.testing.assert_allclose(np.asarray(out.angles)[:, 1], rest[:, 1], atol=1e-12)


BAD_INDICES = [-1, 18, 40, 5.5, 5.0, True, np.array([4]), np.arange(2)]
# per rotation: a fraction of the reachable interval (outside [0, 1]: out of reach) or a value
target_parts = st.one_of(
    st.tuples(st.just("frac"), st.floats(-0.5, 1.5)),
    st.tuples(st.just("frac"), st.sampled_from([0.0, 1.0])),
    st.tuples(st.just("value"), st.sampled_from([INF, -INF, NAN, 1e300, -1e300, 1e12])),
)


@st.composite
def bend_arguments(draw):
    """bendspine's keyword arguments, each out of range or of the wrong kind one time in
    twelve (so that most calls are valid), else in range; the initiator then lies in the
    joint range."""

    def pick(good, bad):
        return draw(bad if draw(st.integers(0, 11)) == 0 else good)

    index = st.one_of(st.integers(0, 17), st.integers(0, 17).map(np.int64))
    pairs = st.tuples(st.integers(0, 17), st.integers(0, 17)).map(lambda p: tuple(sorted(p)))
    bad_pairs = st.sampled_from([(5, 2), (0, 18), (-1, 4), (0.5, 3), (3,)])
    if draw(st.integers(0, 11)) == 0:
        joint_range, (a, b) = draw(bad_pairs), (0, 17)
    else:
        joint_range = draw(st.one_of(st.none(), pairs))
        a, b = (0, 17) if joint_range is None else joint_range
    inside = st.integers(a, b)
    return dict(
        initiator=pick(inside, st.one_of(index, st.sampled_from(BAD_INDICES))),
        resistor=pick(st.one_of(st.none(), index), st.sampled_from(BAD_INDICES)),
        resistance=pick(
            st.one_of(st.floats(0.0, 1.0), st.sampled_from([0.0, 1.0])),
            st.sampled_from([-0.2, 1.5, NAN, INF, -INF]),
        ),
        joint_range=joint_range,
        spread=pick(st.floats(0.05, 20.0), st.sampled_from([0.0, -1.0, NAN, INF])),
        zero_interpolation=draw(st.booleans()),
    )


def _is_index(v):
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool) and 0 <= v <= 17


def _in_range(kw):
    """Whether bendspine must accept these arguments."""
    i, r, res, rng, spread = (
        kw[k] for k in ("initiator", "resistor", "resistance", "joint_range", "spread")
    )
    a, b = (0, 17) if rng is None else (rng + (None, None))[:2]
    return (
        _is_index(i)
        and (r is None or _is_index(r))
        and 0 <= res <= 1
        and np.isfinite(spread)
        and spread > 0
        and (rng is None or (len(rng) == 2 and all(_is_index(x) for x in rng) and a <= b))
        and (not _is_index(i) or rng is None or a <= i <= b)
    )


@settings(max_examples=200, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.sampled_from(["uniform", "limits", "rest", "beyond"]),
    st.tuples(target_parts, target_parts, target_parts),
    bend_arguments(),
)
def test_any_arguments_give_an_error_or_a_valid_bend(spine, seed, kind, parts, kw):
    """Random arguments, in range or not: out of range raises ValueError; otherwise the angles
    are finite and within the limits, frozen joints stay, the sum is the target wherever
    reached, and reached is exactly "finite and within what the active joints can reach"."""
    n = 18
    lo, hi, rest = (np.asarray(x) for x in (spine.lower, spine.upper, spine.rest))
    rng = np.random.default_rng(seed)
    u = rng.uniform(size=lo.shape)
    current = {
        "uniform": lo + (hi - lo) * u,
        "limits": np.where(u < 0.5, lo, hi),
        "rest": rest,
        "beyond": lo + (hi - lo) * (1.4 * u - 0.2),  # partly outside the limits: clipped
    }[kind]
    clipped = np.clip(current, lo, hi)
    valid = _in_range(kw)
    event(f"arguments in range: {valid}")
    a, b = kw["joint_range"] if valid and kw["joint_range"] is not None else (0, n - 1)
    active = (np.arange(n) >= a) & (np.arange(n) <= b)
    reach_lo = np.where(active[:, None], lo, clipped).sum(0)
    reach_hi = np.where(active[:, None], hi, clipped).sum(0)
    target = np.array(
        [
            reach_lo[k] + x * (reach_hi[k] - reach_lo[k]) if how == "frac" else x
            for k, (how, x) in enumerate(parts)
        ]
    )
    if not valid:
        with pytest.raises(ValueError, match="^bendspine: "):
            db.bendspine(spine, current, target, **kw)
        return
    out = db.bendspine(spine, current, target, **kw)
    angles, reached = np.asarray(out.angles), np.asarray(out.reached)
    assert np.all(np.isfinite(angles))
    assert np.all(angles >= lo - 1e-9) and np.all(angles <= hi + 1e-9)
    np.testing.assert_array_equal(angles[~active], clipped[~active])
    sums = angles.sum(0)
    finite = np.isfinite(target)
    margin = 1e-9 * np.maximum(1.0, np.abs(np.where(finite, target, 0.0)))
    inside = finite & (target >= reach_lo - margin) & (target <= reach_hi + margin)
    strictly_inside = finite & (target >= reach_lo + margin) & (target <= reach_hi - margin)
    assert not np.any(reached & ~inside)
    assert np.all(reached[strictly_inside])
    np.testing.assert_allclose(sums[reached], target[reached], rtol=1e-12, atol=1e-9)
    # beyond reach (inf included) the active joints are at their limits; NaN: nothing moves
    up, down = ~np.isnan(target) & (target > reach_hi + margin), target < reach_lo - margin
    np.testing.assert_allclose(angles[active][:, up], hi[active][:, up], atol=1e-12)
    np.testing.assert_allclose(angles[active][:, down], lo[active][:, down], atol=1e-12)
    np.testing.assert_array_equal(angles[:, np.isnan(target)], clipped[:, np.isnan(target)])


def test_float32_keeps_the_limits_and_reaches_feasible_targets(spine):
    """The same guarantees in float32, to its rounding (limits 1e-5 rad, sums the default
    tol of 2e-4 rad)."""
    f32 = jax.tree.map(lambda x: x.astype(jnp.float32) if isinstance(x, jax.Array) else x, spine)
    lo, hi = np.asarray(f32.lower, float), np.asarray(f32.upper, float)
    rng = np.random.default_rng(0)
    for k in range(12):
        current = (
            np.where(rng.uniform(size=lo.shape) < 0.5, lo, hi)
            if k % 2
            else lo + (hi - lo) * rng.uniform(size=lo.shape)
        )
        frac = rng.uniform(-0.2, 1.2, size=3)
        target = lo.sum(0) + frac * (hi - lo).sum(0)
        target[k % 3] = (INF, -INF, NAN)[k % 3] if k >= 9 else target[k % 3]
        out = db.bendspine(
            f32,
            current.astype(np.float32),
            target.astype(np.float32),
            initiator=int(rng.integers(18)),
            resistor=int(rng.integers(18)),
            resistance=float(rng.choice([0.0, 1.0, rng.uniform()])),
            zero_interpolation=bool(k % 4 < 2),
        )
        assert out.angles.dtype == jnp.float32
        a = np.asarray(out.angles, float)
        assert np.all(np.isfinite(a)) and np.all(a >= lo - 1e-5) and np.all(a <= hi + 1e-5)
        reached = np.asarray(out.reached)
        inside = np.isfinite(target) & (frac > 0.001) & (frac < 0.999)
        assert np.all(reached[inside]) and not np.any(reached[~np.isfinite(target)])
        assert not np.any(reached & ((frac < -0.001) | (frac > 1.001)))
        np.testing.assert_allclose(a.sum(0)[reached], target[reached], atol=2e-4 * 5)
