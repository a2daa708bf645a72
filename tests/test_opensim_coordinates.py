"""OpenSim's gait-model coordinates of a pose (`diffbody._opensim_coordinates`): zero in the
standard position, OpenSim's signs (the knee negative in flexion), the pelvis's translation
and turn read in OpenSim's ground, the model's frames applied where given, finite
derivatives. The round trip through OpenSim itself: tests/mocap/test_mocap.py."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree
from test_joint_angles import random_pose, with_rows

import diffbody as db
from diffbody._opensim_coordinates import ModelFrames, coordinate_names, opensim_coordinates
from diffbody._rotations import exp_rotvec

IDENTITY = ModelFrames(jnp.eye(3), jnp.eye(3), jnp.zeros(3))


@pytest.fixture(scope="module")
def coords_of(male50):
    return jax.jit(lambda pose, frames: opensim_coordinates(male50, pose, frames))


def _floats(c: dict) -> dict[str, float]:
    return {k: float(v) for k, v in c.items()}


def test_the_standard_position_is_every_rotation_zero(male50, coords_of):
    c = _floats(coords_of(male50.rest_pose(), None))
    assert list(c) == sorted(coordinate_names())  # jit sorts a dict's keys
    rotations = {k: v for k, v in c.items() if k not in ("pelvis_tx", "pelvis_ty", "pelvis_tz")}
    assert max(abs(v) for v in rotations.values()) < 1e-9
    # gait2354's pelvis origin: 7 cm in front of and above the hip centres, on the midline
    k = db.forward(male50, male50.rest_pose())
    hips = (k.joint_positions[male50.joint_index("left_hip")] + k.joint_positions[
        male50.joint_index("right_hip")]) / 2  # fmt: skip
    assert c["pelvis_tx"] - float(hips[0]) == pytest.approx(0.0707, rel=0.05)
    assert c["pelvis_ty"] - float(hips[2]) == pytest.approx(0.0661, rel=0.05)
    assert c["pelvis_tz"] == pytest.approx(-float(hips[1]), abs=1e-9)


def test_the_knee_is_negative_in_flexion_and_the_rest_as_isb(male50, coords_of):
    """OpenSim's knee_angle is minus ISB's knee flexion; every other joint coordinate is the
    ISB angle of the same name."""
    pose = random_pose(male50, 3)
    c = _floats(coords_of(pose, None))
    isb = {k: float(v) for k, v in jax.jit(lambda p: db.joint_angles(male50, p))(pose).items()}
    for s in "rl":
        assert c[f"knee_angle_{s}"] == pytest.approx(-isb[f"knee_flexion_{s}"], abs=1e-9)
        for name in ("hip_flexion", "hip_adduction", "ankle_angle", "arm_flex", "elbow_flex"):
            assert c[f"{name}_{s}"] == pytest.approx(isb[f"{name}_{s}"], abs=1e-9)
    bent = with_rows(male50, {"right_shank": (np.pi, np.pi - 0.6, 0.0)})
    assert float(coords_of(bent, None)["knee_angle_r"]) == pytest.approx(-np.degrees(0.6))


def test_the_pelvis_moves_and_turns_in_opensim_s_ground(male50, coords_of):
    """Moved by d in diffbody's world (x forward, y left, z up) the pelvis moves by
    (d_x, d_z, -d_y) in OpenSim's ground (X forward, Y up, Z right); the whole body turned
    about the vertical is pelvis_rotation."""
    rest = male50.rest_pose()
    d = np.array([0.3, -0.2, 0.1])
    moved = db.Pose(position=rest.position + d, angles=rest.angles)
    a, b = _floats(coords_of(rest, None)), _floats(coords_of(moved, None))
    got = [b[f"pelvis_t{x}"] - a[f"pelvis_t{x}"] for x in "xyz"]
    assert got == pytest.approx([0.3, 0.1, 0.2], abs=1e-9)
    angles = np.array(rest.angles)
    angles[0, 2] += 0.4  # the whole body's twist: a turn to the left about the vertical
    turned = _floats(coords_of(db.Pose(position=rest.position, angles=jnp.asarray(angles)), None))
    assert turned["pelvis_rotation"] == pytest.approx(np.degrees(0.4), abs=1e-6)
    assert abs(turned["pelvis_tilt"]) < 1e-6 and abs(turned["hip_flexion_r"]) < 1e-6


def test_the_model_s_frames_turn_what_is_read_in_them(male50, coords_of):
    """A model whose torso frame is ours turned 10 degrees about Z reads lumbar extension 10
    degrees less; its pelvis turned as much, pelvis tilt 10 more, the hips' flexion and the
    lumbar extension 10 less; its pelvis origin where it says. Identity frames change
    nothing but the origin."""
    pose = random_pose(male50, 5)
    plain = _floats(coords_of(pose, None))
    same = _floats(coords_of(pose, IDENTITY._replace(pelvis_origin=jnp.array([0.07, 0.066, 0]))))
    for k in plain:
        if not k.startswith("pelvis_t"):
            assert same[k] == pytest.approx(plain[k], abs=1e-6)
    turn = exp_rotvec(jnp.array([0.0, 0.0, np.radians(10.0)]))
    torso = _floats(coords_of(pose, IDENTITY._replace(R_torso=turn)))
    assert torso["lumbar_extension"] == pytest.approx(plain["lumbar_extension"] + 10, abs=0.5)
    pelvis = _floats(coords_of(random_pose(male50, 5, 0.0), IDENTITY._replace(R_pelvis=turn)))
    assert pelvis["pelvis_tilt"] == pytest.approx(10.0, abs=1e-6)
    assert pelvis["hip_flexion_r"] == pytest.approx(-10.0, abs=1e-6)
    assert pelvis["lumbar_extension"] == pytest.approx(-10.0, abs=1e-6)


def test_derivatives_agree_and_stay_finite_at_the_standard_position(male50):
    """jacfwd = jacrev = central differences of every coordinate in the pose's angles and
    position, at a random pose and at the standard position (every Cardan angle at 0)."""
    for pose in (random_pose(male50, 7), male50.rest_pose()):
        fwd, rev, fd = _coordinate_derivatives(male50, pose)
        assert np.all(np.isfinite(fwd)) and np.allclose(fwd, rev, atol=1e-8)
        assert np.allclose(fd, fwd[:, FD_COLUMN], atol=1e-5)


FD_COLUMN = 5  # the flat pose's entry differenced


@eqx.filter_jit
def _coordinate_derivatives(body: db.Body, pose: db.Pose):
    """d(coordinates but the shoulder's)/d(flat pose) by forward mode, reverse mode, and
    central differences along entry `FD_COLUMN`: one program per pose structure."""
    flat, unravel = ravel_pytree(pose)

    def f(x):
        c = opensim_coordinates(body, unravel(x))
        return jnp.stack([c[k] for k in coordinate_names() if "shoulder" not in k])

    e = jnp.zeros_like(flat).at[FD_COLUMN].set(1e-6)
    return jax.jacfwd(f)(flat), jax.jacrev(f)(flat), (f(flat + e) - f(flat - e)) / 2e-6
