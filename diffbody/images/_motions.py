"""Synthetic motions of the default body for image-sequence analysis: walking-like and
reaching, as joint trajectories of a `JointTree` in the world (m).

Both are smooth (sums of sinusoids), every joint within the body's limits, the spine,
neck and head held at rest so that every part of the default tree is rigid (the trunk,
pelvis to C7, moves as one: its sway is a rotation of the whole body about the pelvis
centre). Frames are at `fps` per second.
"""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import Body, Pose
from .._kinematics import forward
from .._limits import angles_from_swing
from ._joint_tree import JointTree, observed_points


def _rot(yaw, pitch, roll) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll), (T, 3, 3): pitch > 0 leans forward, roll > 0 to the right."""
    cy, sy, cp, sp, cr, sr = (f(a) for a in (yaw, pitch, roll) for f in (np.cos, np.sin))
    o, z = np.ones_like(yaw), np.zeros_like(yaw)
    Rz = np.stack(
        [np.stack([cy, -sy, z], -1), np.stack([sy, cy, z], -1), np.stack([z, z, o], -1)], -2
    )
    Ry = np.stack(
        [np.stack([cp, z, sp], -1), np.stack([z, o, z], -1), np.stack([-sp, z, cp], -1)], -2
    )
    Rx = np.stack(
        [np.stack([o, z, z], -1), np.stack([z, cr, -sr], -1), np.stack([z, sr, cr], -1)], -2
    )
    return Rz @ Ry @ Rx


def _joints(
    body: Body,
    tree: JointTree,
    swing: dict[str, np.ndarray],
    R_world_body: np.ndarray,
    offset: np.ndarray,
) -> Float[Array, "n_frames n_obs 3"]:
    """Observed joints (T, J, 3) of the body with per-frame swing vectors (segment -> (T, 2)
    rad), turned by R_world_body (T, 3, 3) about the pelvis centre and shifted by offset
    (T, 3) m."""
    n = len(R_world_body)
    w = np.zeros((n, body.n_segments, 2))
    for name, value in swing.items():
        w[:, body.segment_index(name)] = value
    dtype = body.lengths.dtype

    def one(w_t):
        angles = angles_from_swing(body, w_t, jnp.zeros(body.n_segments, dtype))
        kin = forward(body, Pose(body.rest_position, angles))
        return observed_points(tree, body, kin.joint_positions, kin.feature_points)

    p = jax.jit(jax.vmap(one))(jnp.asarray(w, dtype))
    centre = body.rest_position
    R = jnp.asarray(R_world_body, dtype)
    return jnp.einsum("tij,tkj->tki", R, p - centre) + centre + jnp.asarray(offset, dtype)[:, None]


def walking_motion(
    body: Body,
    tree: JointTree,
    n_frames: int,
    fps: float = 60.0,
    period: float = 1.1,
    speed: float = 0.0,
    turn_deg: float = 30.0,
    turn_period: float = 8.0,
) -> Float[Array, "n_frames n_obs 3"]:
    """Walking-like motion: hips flex -11..+23 deg, knees 4..36 deg, arms swing against the
    legs, the pelvis turns, leans and bobs with the stride (`period` s). The walker moves
    forward at `speed` m/s (0: on a treadmill) and its heading swings +-`turn_deg` over
    `turn_period` s, so that the camera sees the parts from changing sides."""
    t = np.arange(n_frames) / fps
    ph = 2 * np.pi * t / period
    swing = {}
    for side, shift, sign in (("left", 0.0, 1.0), ("right", np.pi, -1.0)):
        p = ph + shift
        flex = 0.10 + 0.30 * np.sin(p)
        knee = 0.35 + 0.20 * np.sin(p + 1.3) + 0.06 * np.sin(2 * p + 0.4)
        swing[f"{side}_thigh"] = np.stack([sign * (0.04 + 0.04 * np.sin(p)), flex], -1)
        swing[f"{side}_shank"] = np.stack([0 * p, -knee], -1)
        swing[f"{side}_upper_arm"] = np.stack(
            [sign * (0.12 + 0.03 * np.sin(p)), -0.30 * np.sin(p)], -1
        )
        swing[f"{side}_forearm"] = np.stack([0 * p, 0.45 - 0.20 * np.sin(p)], -1)
    heading = np.radians(turn_deg) * np.sin(2 * np.pi * t / turn_period)
    yaw = heading + 0.10 * np.sin(ph)
    pitch = 0.05 + 0.04 * np.sin(2 * ph + 0.5)
    roll = 0.04 * np.sin(ph)
    forward_dir = np.stack([np.cos(heading), np.sin(heading), 0 * t], -1)
    progress = speed * t
    offset = progress[:, None] * forward_dir
    offset[:, 1] += 0.02 * np.sin(ph)
    offset[:, 2] += 0.02 * np.cos(2 * ph)
    return _joints(body, tree, swing, _rot(yaw, pitch, roll), offset)


def reaching_motion(
    body: Body, tree: JointTree, n_frames: int, fps: float = 60.0, period: float = 3.0
) -> Float[Array, "n_frames n_obs 3"]:
    """Reaching: the right arm lifts forward and out to 86 deg with the elbow straightening,
    the left reaches less and later, the trunk leans forward up to 14 deg and turns +-30
    deg (the legs flex to stay under it), the knees bend a little (a squat-reach); one reach
    every `period` s."""
    t = np.arange(n_frames) / fps
    ph = 2 * np.pi * t / period
    lift = 0.5 * (1 - np.cos(ph))
    lift_l = 0.5 * (1 - np.cos(ph - 1.4))
    lean = 0.24 * lift + 0.03 * np.sin(0.5 * ph)
    knee = 0.15 + 0.25 * lift
    swing = {
        "right_upper_arm": np.stack([-0.1 - 0.5 * lift, 1.5 * lift], -1),
        "right_forearm": np.stack([0 * t, 1.3 - 1.0 * lift], -1),
        "left_upper_arm": np.stack([0.1 + 0.3 * lift_l, 1.0 * lift_l], -1),
        "left_forearm": np.stack([0 * t, 0.9 - 0.6 * lift_l], -1),
    }
    for side in ("left", "right"):
        swing[f"{side}_thigh"] = np.stack([0 * t, lean + 0.5 * knee], -1)
        swing[f"{side}_shank"] = np.stack([0 * t, -knee], -1)
    yaw = 0.5 * np.sin(0.5 * ph + 0.3)
    roll = 0.05 * np.sin(ph)
    offset = np.zeros((n_frames, 3))
    offset[:, 2] = -0.03 * knee
    return _joints(body, tree, swing, _rot(yaw, lean, roll), offset)
