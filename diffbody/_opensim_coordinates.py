"""OpenSim's gait-model coordinates of a pose: what a column named after an OpenSim coordinate
means in gait2354, gait2392 and Rajagopal 2016's full-body model, which share these names,
signs, zeros and units (docs/design.md, section 7, "OpenSim's coordinates").

- The pelvis, ground -> pelvis: `pelvis_tilt`, `pelvis_list`, `pelvis_rotation`, the Z-X-Y
  Cardan angles of the model's pelvis frame in OpenSim's ground (X forward, Y up, Z right),
  and `pelvis_tx`, `pelvis_ty`, `pelvis_tz`, where that frame's origin lies in the ground, m.
- The joints: the ISB angles (`joint_angles`) with OpenSim's sign, `OPENSIM_FROM_ISB`. Every
  body frame of the gait models is parallel to the ground in their default pose, as every
  ISB anatomical frame of the standard position is, and their hip, lumbar and shoulder
  coordinates are the same Z-X-Y sequences. The knee is OpenSim's `knee_angle`, negative in
  flexion; the ankle is about OpenSim's oblique talocrural axis, ours about the shank's Z;
  `subtalar_angle` and `mtp_angle` have no counterpart and are left out (the model's
  default, 0, when a file drives it).
- The zeros. A model's pelvis and torso frames sit on the bones otherwise than our pelvis's
  and thorax's anatomical frames: gait2354's torso frame is turned about 14 degrees about Z
  from our thorax's (the torso is one rigid body from L5-S1 up). `ModelFrames` says where
  the model's pelvis and torso frames, and its pelvis origin, lie in ours
  (`diffbody.mocap.model_frames` finds them from where the model's markers and ours sit on
  each bone); the pelvis's, lumbar, hip and shoulder coordinates are read in them. Without
  them the frames are taken as ours, and the pelvis origin at gait2354's hip centres,
  (-0.0707, -0.0661, +-0.0835) m in its pelvis frame, scaled to the body's hip width.

Rotations are in degrees (a .mot's `inDegrees=yes`), translations in metres.
"""

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._body import Body, Pose
from ._joint_angles import (
    R_WORLD_ISB,
    anatomical_of_twisted,
    angles_of_frames,
    cardan_zxy,
    thorax_segment,
)
from ._kinematics import forward

GAIT2354_HIP_IN_PELVIS = (-0.0707, -0.0661, 0.0835)  # m, the right hip centre, pelvis frame
PELVIS = ("pelvis_tilt", "pelvis_list", "pelvis_rotation", "pelvis_tx", "pelvis_ty", "pelvis_tz")
# OpenSim's coordinate (side-free) <- (our ISB angle, the factor from ours to OpenSim's).
OPENSIM_FROM_ISB: dict[str, tuple[str, float]] = {
    "hip_flexion": ("hip_flexion", 1.0),
    "hip_adduction": ("hip_adduction", 1.0),
    "hip_rotation": ("hip_rotation", 1.0),
    "knee_angle": ("knee_flexion", -1.0),
    "ankle_angle": ("ankle_angle", 1.0),
    "lumbar_extension": ("lumbar_extension", 1.0),
    "lumbar_bending": ("lumbar_bending", 1.0),
    "lumbar_rotation": ("lumbar_rotation", 1.0),
    "arm_flex": ("arm_flex", 1.0),
    "arm_add": ("arm_add", 1.0),
    "arm_rot": ("arm_rot", 1.0),
    "elbow_flex": ("elbow_flex", 1.0),
}
LUMBAR = ("lumbar_extension", "lumbar_bending", "lumbar_rotation")


class ModelFrames(NamedTuple):
    """Where an OpenSim model's frames lie in ours (module docstring): its pelvis frame in
    our pelvis's anatomical frame, its torso frame in our thorax's (rotations, (3, 3)), and
    its pelvis origin in our pelvis's anatomical frame from the hip centres' midpoint (3,) m."""

    R_pelvis: Float[Array, "3 3"]
    R_torso: Float[Array, "3 3"]
    pelvis_origin: Float[Array, "3"]


def coordinate_names() -> tuple[str, ...]:
    """The keys of `opensim_coordinates`' result, in its order: the pelvis's six, then each
    joint's right and left coordinates, then the lumbar ones."""
    sided = [n for n in OPENSIM_FROM_ISB if n not in LUMBAR]
    return PELVIS + tuple(f"{n}_{s}" for n in sided for s in "rl") + LUMBAR


def opensim_coordinates(
    body: Body, pose: Pose, frames: ModelFrames | None = None
) -> dict[str, Float[Array, ""]]:
    """OpenSim's gait-model coordinates of a pose (module docstring): degrees for rotations,
    metres for translations, in OpenSim's ground (X forward, Y up, Z right; diffbody's world
    read from a lab in OpenSim's axes, `read_trc`'s default).

    Pure JAX (jit, vmap, grad), as `joint_angles`.

    Args:
        body: a body with the default bodies' limbs and a thorax (`joint_angles`).
        pose: one pose.
        frames: where the model's pelvis and torso frames lie in ours
            (`diffbody.mocap.model_frames`); None: ours, gait2354's pelvis origin.
    """
    k = forward(body, pose)
    R = anatomical_of_twisted(body, k.R_world_twisted)
    right = k.joint_positions[body.joint_index("right_hip")]
    left = k.joint_positions[body.joint_index("left_hip")]
    if frames is None:
        hx, hy, hz = GAIT2354_HIP_IN_PELVIS
        scale = jnp.linalg.norm(right - left) / (2 * hz)
        origin = -scale * jnp.asarray(np.array([hx, hy, 0.0]), R.dtype)
    else:
        pelvis_segments = {body.segment_index("pelvis")} | {body.parent[s] for s in body.thighs}
        for s in sorted(pelvis_segments):  # the hips' parents are rigid with the pelvis
            R = R.at[s].set(R[s] @ frames.R_pelvis)
        thorax = thorax_segment(body)
        R = R.at[thorax].set(R[thorax] @ frames.R_torso)
        origin = frames.pelvis_origin
    isb = angles_of_frames(body, R)
    out: dict[str, Array] = {}
    lab = jnp.asarray(R_WORLD_ISB, R.dtype)  # the ground's axes in the world
    R_world_pelvis = R[body.segment_index("pelvis")]
    for name, angle in zip(PELVIS[:3], jnp.degrees(cardan_zxy(lab.T @ R_world_pelvis))):
        out[name] = angle
    for name, value in zip(PELVIS[3:], lab.T @ ((right + left) / 2 + R_world_pelvis @ origin)):
        out[name] = value
    for name in coordinate_names()[6:]:
        side = name[-2:] if name.endswith(("_r", "_l")) else ""
        ours, factor = OPENSIM_FROM_ISB[name[: len(name) - len(side)]]
        out[name] = factor * isb[ours + side]
    return out
