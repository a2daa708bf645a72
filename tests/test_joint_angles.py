"""ISB joint angles (diffbody._joint_angles): zero in the standard position, closed forms for
one-axis motions, mirror symmetry, the Bendspine thorax, and derivatives (forward = reverse
= finite differences; finite at the standard position, the shoulder's gimbal lock)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import diffbody as db
from diffbody._joint_angles import (
    LUMBAR_NAMES,
    angle_names,
    euler_yxy,
    joint_angles,
    thorax_segment,
)
from diffbody._rotations import exp_rotvec

# Angles undefined at zero shoulder elevation (module docstring of _joint_angles).
AT_THE_LOCK = {f"{n}_{s}" for n in ("shoulder_elevation_plane", "shoulder_rotation") for s in "rl"}


@pytest.fixture(scope="module")
def angles_of(male50):
    return jax.jit(lambda pose: joint_angles(male50, pose))


def with_rows(body: db.Body, rows: dict[str, tuple[float, float, float]]) -> db.Pose:
    """The standard position with some segments' (theta, phi, tau) replaced."""
    rest = body.rest_pose()
    angles = np.array(rest.angles)
    for name, row in rows.items():
        angles[body.segment_index(name)] = row
    return db.Pose(position=rest.position, angles=jnp.asarray(angles))


def random_pose(body: db.Body, seed: int, scale: float = 0.3) -> db.Pose:
    """The standard position with every row perturbed (the spine's ten times less), the
    arms raised 0.5 rad forward (away from the shoulder's gimbal lock)."""
    rng = np.random.default_rng(seed)
    rest = body.rest_pose()
    angles = np.array(rest.angles)
    spine = [body.segment_index(s) for s in body.spine.segment_names]
    noise = scale * rng.standard_normal(angles.shape)
    noise[spine] /= 10
    angles[1:] += noise[1:]
    for side in ("left", "right"):
        angles[body.segment_index(f"{side}_upper_arm"), 1] -= 0.5
    return db.Pose(position=rest.position, angles=jnp.asarray(angles))


def mirrored(body: db.Body, pose: db.Pose) -> db.Pose:
    """The pose's mirror image in the sagittal plane: left and right rows swapped, azimuths
    and twists negated, the position's Y negated."""
    names = body.segment_names
    angles = np.array(pose.angles)
    out = angles.copy()
    for i, name in enumerate(names):
        other = name.replace("left", "@").replace("right", "left").replace("@", "right")
        out[names.index(other)] = angles[i]
    out[:, 0] *= -1
    out[:, 2] *= -1
    position = np.array(pose.position) * [1.0, -1.0, 1.0]
    return db.Pose(position=jnp.asarray(position), angles=jnp.asarray(out))


@pytest.mark.parametrize("variant", ["male50", "female50"])
def test_zero_in_the_standard_position(variant, request):
    body = request.getfixturevalue(variant)
    angles = joint_angles(body, body.rest_pose())
    assert set(angles) == set(angle_names()) and len(angle_names()) == 35
    assert all(abs(float(v)) < 1e-9 for v in angles.values()), angles
    assert body.segment_names[thorax_segment(body)] == "T1"


@settings(max_examples=8)
@given(
    alpha=st.floats(-0.5, 1.5),
    side=st.sampled_from(["right", "left"]),
    joint=st.sampled_from(["hip", "knee", "elbow"]),
)
def test_one_axis_flexion_reads_the_applied_angle(male50, angles_of, alpha, side, joint):
    """The thigh swung forward by alpha in the sagittal plane (theta 0, phi pi - alpha) is
    hip flexion alpha; the shank swung back (theta pi) knee flexion alpha; the forearm
    forward elbow flexion alpha; every other angle stays 0."""
    segment, theta, name = {
        "hip": ("thigh", 0.0, "hip_flexion"),
        "knee": ("shank", np.pi, "knee_flexion"),
        "elbow": ("forearm", 0.0, "elbow_flex"),
    }[joint]
    pose = with_rows(male50, {f"{side}_{segment}": (theta, np.pi - alpha, 0.0)})
    angles = {k: float(v) for k, v in angles_of(pose).items()}
    key = f"{name}_{side[0]}"
    assert angles[key] == pytest.approx(np.degrees(alpha), abs=1e-9)
    others = {k: v for k, v in angles.items() if k != key and abs(v) > 1e-9}
    assert not others, others


def test_signs_of_the_lower_limb_and_the_spine(male50, angles_of):
    """Dorsiflexion, inversion and internal rotation of the foot, and the twists of the
    thigh, read positive on both sides (the left mirrored); Bendspine's flexion is negative
    lumbar_extension, its lateral bending and axial rotation positive bending and rotation."""
    a = 0.3
    for side, sign in (("right", -1.0), ("left", 1.0)):
        s = side[0]
        foot = {f"{side}_foot": (sign * -a, np.pi / 2, sign * -a)}  # toes in, sole in
        got = angles_of(with_rows(male50, foot))
        assert float(got[f"ankle_rotation_{s}"]) > 10 and float(got[f"ankle_inversion_{s}"]) > 10
        got = angles_of(with_rows(male50, {f"{side}_foot": (0.0, np.pi / 2 - a, 0.0)}))
        assert float(got[f"ankle_angle_{s}"]) == pytest.approx(np.degrees(a), abs=1e-9)
        got = angles_of(with_rows(male50, {f"{side}_thigh": (0.0, np.pi, sign * a)}))
        assert float(got[f"hip_rotation_{s}"]) == pytest.approx(np.degrees(a), abs=1e-9)
    rest = male50.rest_pose()
    total = male50.spine.rest.sum(axis=0)
    for k, (name, sign) in enumerate(zip(LUMBAR_NAMES, (-1, 1, 1))):
        step = jnp.zeros(3).at[(0, 2, 1)[k]].set(0.3)
        pose = db.Pose(position=rest.position, angles=rest.angles, spine_target=total + step)
        got = {n: float(v) for n, v in angles_of(pose).items() if n in LUMBAR_NAMES}
        assert 15 < sign * got[name] < 17.5, got  # the neck's share is above the thorax
        assert all(abs(v) < 1e-6 for n, v in got.items() if n != name), got


@settings(max_examples=6)
@given(seed=st.integers(0, 2**16))
def test_mirror_symmetry(male50, angles_of, seed):
    """A pose and its mirror image: each side's angles are the other side's; the lumbar
    extension is the same, its bending and rotation change sign."""
    pose = random_pose(male50, seed)
    a, b = angles_of(pose), angles_of(mirrored(male50, pose))
    for name in angle_names():
        if name in LUMBAR_NAMES:
            sign = 1.0 if name == "lumbar_extension" else -1.0
            assert float(b[name]) == pytest.approx(sign * float(a[name]), abs=1e-8)
        else:
            other = name[:-1] + {"r": "l", "l": "r"}[name[-1]]
            assert float(b[other]) == pytest.approx(float(a[name]), abs=1e-8), name


def test_batches_by_vmap(male50, angles_of):
    poses = [random_pose(male50, s) for s in range(3)]
    batch = jax.tree.map(lambda *x: jnp.stack(x), *poses)
    out = jax.jit(jax.vmap(lambda p: joint_angles(male50, p)))(batch)
    for i, pose in enumerate(poses):
        one = angles_of(pose)
        for name in angle_names():
            assert float(out[name][i]) == pytest.approx(float(one[name]), abs=1e-10)


def _jacobians(body: db.Body, pose: db.Pose):
    """d(angles)/d(pose angles) by forward mode, reverse mode and central differences."""
    names = angle_names()
    x = jnp.asarray(pose.angles).ravel()
    fwd, rev, fd = _derivatives(body, pose.position, x)
    return names, np.asarray(fwd), np.asarray(rev), np.asarray(fd)


@eqx.filter_jit
def _derivatives(body: db.Body, position, x):
    """`_jacobians`' three, one program for every pose (the pose is an argument)."""
    names = angle_names()

    def f(x):
        p = db.Pose(position=position, angles=x.reshape(-1, 3))
        out = joint_angles(body, p)
        return jnp.stack([out[n] for n in names])

    h = 1e-6
    fd = jax.vmap(lambda e: (f(x + e) - f(x - e)) / (2 * h))(h * jnp.eye(x.size)).T
    return jax.jacfwd(f)(x), jax.jacrev(f)(x), fd


def test_derivatives_agree(male50):
    """Away from the gimbal lock: forward = reverse mode to rounding, and both = central
    differences (degrees per radian, to 1e-5 of the largest)."""
    names, fwd, rev, fd = _jacobians(male50, random_pose(male50, 7))
    assert np.all(np.isfinite(fwd)) and np.allclose(fwd, rev, atol=1e-9)
    scale = np.abs(fwd).max()
    assert np.abs(fwd - fd).max() < 1e-5 * scale


def test_derivatives_finite_at_the_standard_position(male50):
    """At the standard position (zero shoulder elevation, every hanging limb at its pole):
    every derivative finite, forward = reverse mode, and = central differences except the
    two shoulder angles the lock leaves undefined (the elevation, |b| at its apex, reports
    the subgradient 0, as central differences do)."""
    names, fwd, rev, fd = _jacobians(male50, male50.rest_pose())
    assert np.all(np.isfinite(fwd)) and np.all(np.isfinite(rev))
    assert np.allclose(fwd, rev, atol=1e-9)
    keep = [i for i, n in enumerate(names) if n not in AT_THE_LOCK]
    assert np.abs(fwd[keep] - fd[keep]).max() < 1e-5 * np.abs(fwd).max()


@settings(max_examples=10)
@given(
    a=st.floats(-3.0, 3.0),
    b=st.floats(-3.0, -0.05),
    c=st.floats(-3.0, 3.0),
)
def test_yxy_inverts_its_rotation(a, b, c):
    """Ry(a) Rx(b) Ry(c) with b in [-pi, 0) off the lock decomposes into (a, b, c)."""
    Ry = lambda t: exp_rotvec(jnp.array([0.0, t, 0.0]))  # noqa: E731
    Rx = exp_rotvec(jnp.array([b, 0.0, 0.0]))
    got = np.asarray(euler_yxy(Ry(a) @ Rx @ Ry(c)))
    assert got == pytest.approx([a, b, c], abs=1e-8)


def test_yxy_at_the_lock_is_finite():
    """At zero elevation the turn about Y is all axial rotation, and reverse mode is finite."""
    R = exp_rotvec(jnp.array([0.0, 0.4, 0.0]))
    assert np.asarray(euler_yxy(R)) == pytest.approx([0.0, 0.0, 0.4], abs=1e-12)
    g = jax.jacrev(lambda r: euler_yxy(exp_rotvec(r)))(jnp.array([0.0, 0.4, 0.0]))
    assert np.all(np.isfinite(g))
