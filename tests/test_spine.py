"""Bendspine and Movespine (seed 004): properties from the paper, derivatives, the body."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import diffbody as db

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


@pytest.fixture(scope="module")
def bend(spine):
    """bendspine compiled once per zero-interpolation flag; every other input traced."""
    fns = {
        z: jax.jit(
            lambda c, t, i, r, res, rng, z=z: db.bendspine(
                spine,
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
        initiator=9,
        resistor=None,
        resistance=0.0,
        joint_range=None,
        zero_interpolation=True,
    ):
        n = spine.n_joints
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
    """A spine state inside the limits from uniforms in [0, 1]."""
    lo, hi = np.asarray(spine.lower), np.asarray(spine.upper)
    return lo + (hi - lo) * np.asarray(u).reshape(lo.shape)


def _n(spine):
    return spine.n_joints


unit = st.floats(0.0, 1.0)


N_JOINTS = 18


@st.composite
def problems(draw):
    n = N_JOINTS
    u = draw(st.lists(unit, min_size=3 * n, max_size=3 * n))
    lo_j = draw(st.integers(0, n - 1))
    hi_j = draw(st.integers(lo_j, n - 1))
    init = draw(st.integers(lo_j, hi_j))
    res = draw(st.integers(0, n - 1))
    resistance = draw(unit)
    frac = draw(st.lists(unit, min_size=3, max_size=3))
    zero = draw(st.booleans())
    return u, (lo_j, hi_j), init, res, resistance, frac, zero


def _feasible_target(spine, current, rng_, frac):
    """A target within what the active joints can reach, the frozen ones staying."""
    active = np.zeros(spine.n_joints, bool)
    active[rng_[0] : rng_[1] + 1] = True
    lo = np.where(active[:, None], np.asarray(spine.lower), current).sum(0)
    hi = np.where(active[:, None], np.asarray(spine.upper), current).sum(0)
    return lo + (hi - lo) * np.asarray(frac), active


@given(problems())
def test_sum_equals_feasible_target_and_limits_hold(spine, bend, prob):
    u, rng_, init, res, resistance, frac, zero = prob
    current = _state(spine, u)
    target, active = _feasible_target(spine, current, rng_, frac)
    out = bend(current, target, init, res, resistance, rng_, zero)
    a = np.asarray(out.angles)
    np.testing.assert_allclose(a.sum(0), target, atol=1e-9)
    assert bool(np.all(out.reached))
    assert np.all(a >= np.asarray(spine.lower) - 1e-12) and np.all(
        a <= np.asarray(spine.upper) + 1e-12
    )
    np.testing.assert_array_equal(a[~active], current[~active])  # frozen joints never move


@given(problems())
def test_beyond_the_limits_the_spine_stops_at_them(spine, bend, prob):
    u, rng_, init, res, resistance, frac, zero = prob
    current = _state(spine, u)
    lo, hi = np.asarray(spine.lower).sum(0), np.asarray(spine.upper).sum(0)
    target = np.where(np.asarray(frac) > 0.5, hi + 0.3, lo - 0.3)
    out = bend(current, target, init, res, resistance, None, zero)
    assert not np.any(out.reached)
    bound = np.where(np.asarray(frac) > 0.5, np.asarray(spine.upper), np.asarray(spine.lower))
    np.testing.assert_allclose(out.angles, bound, atol=1e-12)
    np.testing.assert_allclose(out.shortfall, target - bound.sum(0), atol=1e-12)


@given(st.lists(unit, min_size=54, max_size=54), st.integers(0, 17), st.booleans())
def test_full_participation_puts_every_joint_at_its_limit(spine, bend, u, init, up):
    current = _state(spine, u)
    bound = np.asarray(spine.upper if up else spine.lower)
    out = bend(current, bound.sum(0), init)
    np.testing.assert_allclose(out.angles, bound, atol=1e-9)


@given(problems(), unit, unit)
def test_more_resistance_never_moves_the_resistive_region_more(spine, bend, prob, r1, r2):
    u, _, init, res, _, frac, zero = prob
    """With zero interpolation a move across the rest posture first returns every joint to
    rest, resistance or not (the seed interpolates through it); so there we start at rest."""
    if res == init:
        return
    current = np.asarray(spine.rest) if zero else _state(spine, u)
    target, _ = _feasible_target(spine, current, (0, _n(spine) - 1), frac)
    lo_r, hi_r = sorted((r1, r2))
    region = np.arange(_n(spine))
    region = region >= res if res > init else region <= res
    moved = [
        np.abs(np.asarray(bend(current, target, init, res, r, None, zero).angles) - current)[
            region
        ].sum(0)
        for r in (lo_r, hi_r)
    ]
    assert np.all(moved[1] <= moved[0] + 1e-9)


def test_full_resistance_keeps_the_resistive_region_until_the_active_one_is_spent(spine, bend):
    rest = np.asarray(spine.rest)
    hi = np.asarray(spine.upper)
    init, res = 16, 10  # lumbar initiator, resistor at T10-T11: the thorax resists
    active_room = (hi - rest)[res + 1 :].sum(0)
    small = rest.sum(0) + 0.9 * active_room
    out = np.asarray(bend(rest, small, init, res, 1.0).angles)
    np.testing.assert_allclose(out[: res + 1], rest[: res + 1], atol=1e-12)
    big = rest.sum(0) + active_room + 0.05
    out = np.asarray(bend(rest, big, init, res, 1.0).angles)
    np.testing.assert_allclose(out[res + 1 :], hi[res + 1 :], atol=1e-12)
    assert np.all(np.abs(out[: res + 1] - rest[: res + 1]).sum(0) > 0.01)


@pytest.mark.parametrize("init", [2, 6, 9, 13, 16])
@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_initiator_moves_most_on_a_fresh_bend(spine, bend, init, axis, sign):
    rest = np.asarray(spine.rest)
    room = np.asarray(spine.upper if sign > 0 else spine.lower)[:, axis] - rest[:, axis]
    target = rest.sum(0).copy()
    target[axis] += 0.1 * room.sum()
    moved = np.abs(np.asarray(bend(rest, target, init).angles)[:, axis] - rest[:, axis])
    assert np.argmax(moved) == init
    # and it falls off with distance on either side
    assert moved[max(init - 4, 0)] < moved[init] and moved[min(init + 4, 17)] < moved[init]


def test_zero_interpolation_goes_through_the_rest_posture(spine, bend):
    """Yes: crossing the rest posture, every joint is at rest when the sum is the rest sum.
    No: only the limits are interpolated toward, so returning takes another path."""
    rest = np.asarray(spine.rest)
    flexed = np.asarray(bend(rest, rest.sum(0) + np.array([0.5, 0, 0]), 4).angles)
    back = [
        np.asarray(bend(flexed, rest.sum(0), 14, zero_interpolation=z).angles)
        for z in (True, False)
    ]
    np.testing.assert_allclose(back[0], rest, atol=1e-12)
    assert np.abs(back[1] - rest).max() > 1e-3
    np.testing.assert_allclose(back[1].sum(0), rest.sum(0), atol=1e-9)
    # Past the rest posture, "yes" starts from rest: the result does not remember the flexion.
    ext = rest.sum(0) - np.array([0.3, 0, 0])
    np.testing.assert_allclose(bend(flexed, ext, 14).angles, bend(rest, ext, 14).angles, atol=1e-12)


def test_gradient_with_respect_to_the_target(spine):
    rest = jnp.asarray(spine.rest)
    f = jax.jit(lambda t: db.bendspine(spine, rest, t, initiator=9).angles)
    t0 = rest.sum(0) + jnp.array([0.2, -0.15, 0.1])
    jf, jr = jax.jacfwd(f)(t0), jax.jacrev(f)(t0)
    np.testing.assert_allclose(jf, jr, atol=1e-12)
    h = 1e-6
    fd = np.stack([(f(t0 + h * e) - f(t0 - h * e)) / (2 * h) for e in np.eye(3)], -1)
    np.testing.assert_allclose(fd, jf, atol=1e-6)
    assert np.all(np.isfinite(jax.jacfwd(f)(rest.sum(0))))  # at rest: zero movement


def test_vmap_equals_a_loop(spine, bend):
    rng = np.random.default_rng(0)
    currents = np.stack([_state(spine, rng.uniform(size=54)) for _ in range(4)])
    targets = np.stack(
        [_feasible_target(spine, c, (0, 17), rng.uniform(size=3))[0] for c in currents]
    )
    batched = jax.jit(jax.vmap(lambda c, t: db.bendspine(spine, c, t, initiator=5).angles))(
        currents, targets
    )
    for k in range(4):
        np.testing.assert_allclose(batched[k], bend(currents[k], targets[k], 5).angles, atol=1e-13)


@pytest.mark.parametrize("figure", FIGURES)
def test_the_seeds_figure_targets(spine, bend, figure):
    target = np.asarray(figure) * DEG
    out = bend(np.asarray(spine.rest), target, 12)
    lo, hi = np.asarray(spine.lower).sum(0), np.asarray(spine.upper).sum(0)
    feasible = (target >= lo) & (target <= hi)
    np.testing.assert_array_equal(np.asarray(out.reached), feasible)
    a = np.asarray(out.angles)
    np.testing.assert_allclose(a.sum(0)[feasible], target[feasible], atol=1e-9)
    nearest = np.clip(target, lo, hi)
    np.testing.assert_allclose(a.sum(0), nearest, atol=1e-9)


def test_movespine_scans_a_sequence(spine, bend):
    rest = np.asarray(spine.rest)
    t = np.linspace(0, 1, 9)
    targets = rest.sum(0) + np.stack(
        [0.4 * np.sin(2 * np.pi * t), 0 * t, 0.2 * np.sin(4 * np.pi * t)], -1
    )
    out = db.movespine(spine, rest, targets, initiator=8, zero_interpolation=False)
    assert out.angles.shape == (9, 18, 3)
    np.testing.assert_allclose(out.angles.sum(1), targets, atol=1e-9)
    prev = rest
    for k in range(9):  # each step starts where the last ended
        np.testing.assert_allclose(
            out.angles[k], bend(prev, targets[k], 8, zero_interpolation=False).angles, atol=1e-12
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

    doc = json.loads(db._loading.data_file("spine.json").read_text())
    doc["joints"][3]["rest_deg"][0] = 90.0
    path = tmp_path / "spine.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(
        db.BodyFileError,
        match=r"spine.json: joint 'T3_T4' \(joints\[3\]\), field 'limits_deg.flexion'",
    ):
        db.load_spine(path)
    del doc["joints"][2]["limits_deg"]
    path.write_text(json.dumps(doc))
    with pytest.raises(db.BodyFileError, match="joint 'T2_T3'"):
        db.load_spine(path)


def test_bad_arguments_are_rejected(spine):
    with pytest.raises(ValueError, match="initiator 18"):
        db.bendspine(spine, spine.rest, jnp.zeros(3), initiator=18)
    with pytest.raises(ValueError, match="outside joint_range"):
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
    batch = jax.vmap(
        lambda t: db.forward(male50, db.Pose(rest.position, rest.angles, spine_target=t))
    )
    np.testing.assert_allclose(
        batch(targets).sphere_centers[1], fk(male50, rest).sphere_centers, atol=1e-12
    )


def test_spine_target_needs_a_spine(tmp_path):
    from bodies import mini_doc, write

    body = db.load_body(write(mini_doc(), tmp_path / "mini.json"))
    pose = body.rest_pose()
    with pytest.raises(ValueError, match="no spine database"):
        db.forward(body, db.Pose(pose.position, pose.angles, spine_target=jnp.zeros(3)))
    doc = mini_doc()
    doc["spine"] = str(db._loading.data_file("spine.json"))
    with pytest.raises(db.BodyFileError, match="'spine'.*moves segment 'neck'"):
        db.load_body(write(doc, tmp_path / "mini_spine.json"))
