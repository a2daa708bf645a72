"""Joint angles in the ISB's joint coordinate systems, comparable with OpenSim's gait models.

`joint_angles(body, pose)` builds the ISB anatomical frame of each segment from the frames
of `forward` and reports the joint angles in degrees as the International Society of
Biomechanics recommends them:

- Wu G, Siegler S, Allard P, et al. (2002), "ISB recommendation on definitions of joint
  coordinate system of various joints for the reporting of human joint motion - part I:
  ankle, hip, and spine", J Biomech 35:543-548: the introduction (X anterior, Y superior,
  Z to the right; the left side mirrored), and the sections on the ankle joint complex
  (tibia/fibula -> calcaneus), the hip (pelvis -> femur) and the spine (the lower body ->
  the upper one).
- Wu G, van der Helm FCT, Veeger HEJ, et al. (2005), "... part II: shoulder, elbow, wrist
  and hand", J Biomech 38:981-992: the shoulder section's JCS for the humerus relative to
  the thorax (the Y-X-Y sequence) and the elbow section's (humerus -> forearm).
- Grood ES, Suntay WJ (1983), "A joint coordinate system for the clinical description of
  three-dimensional motions: application to the knee", J Biomech Eng 105:136-144 (the
  knee: flexion about the femur's Z, positive in flexion).

Anatomical frames. ISB's frames are built from bony landmarks; the sphere body has none, so
each segment's anatomical frame is its twisted cross of axes (`Kinematics.R_world_twisted`:
the frame at the distal end, which carries the long-axis rotation of the limb, as the ISB's
epicondyle and malleolus axes do) turned by one fixed rotation per segment, read off the
standard position: there every anatomical frame is X forward, Y up, Z to the right. So in
the standard position (upright, feet flat, arms at the sides, palms toward the thighs) every
angle is 0 (the shoulder's plane of elevation and axial rotation, undefined there, are
reported as 0 and the whole turn about the humerus; below). The segments:

- pelvis: "pelvis" for the lumbar joint; each thigh's parent ("right_pelvis",
  "left_pelvis") for its hip, rigid with "pelvis" in the default bodies.
- thorax: "thorax" or "chest" when the body has one, else the segment the clavicles hang from
  ("T1": its frame turns with the whole thoracolumbar spine, Bendspine included).
- thigh (femur), shank (tibia), foot (calcaneus): "{side}_thigh", "{side}_shank",
  "{side}_foot"; upper arm (humerus), forearm: "{side}_upper_arm", "{side}_forearm".

Joint angles are Cardan decompositions of the distal frame in the proximal one (the JCS of
Grood & Suntay is the same decomposition): R = R1(a) R2(b) R3(c), each turn right-handed
about an axis of the proximal frame (1), the floating axis (2) and an axis of the distal
frame (3). The left side is mirrored in the sagittal plane first (Wu 2002), so
flexion, adduction and internal rotation have the same sign on both sides.

| name (_r, _l) | joint: sequence, angle | positive (ISB) | OpenSim coordinate |
| --- | --- | --- | --- |
| hip_flexion | pelvis -> thigh: Z-X-Y, 1st | flexion | hip_flexion (a) |
| hip_adduction | 2nd | adduction | hip_adduction (a) |
| hip_rotation | 3rd | internal rotation | hip_rotation (a) |
| knee_flexion | thigh -> shank: Z-X-Y, -(1st) | flexion (Grood & Suntay) | -knee_angle (b) |
| knee_adduction | 2nd | adduction (varus) | - (b) |
| knee_rotation | 3rd | internal rotation | - (b) |
| ankle_angle | shank -> foot: Z-X-Y, 1st | dorsiflexion | ankle_angle (c) |
| ankle_inversion | 2nd | inversion | - (c) |
| ankle_rotation | 3rd | internal rotation (foot adduction) | - (c) |
| lumbar_extension | pelvis -> thorax: Z-X-Y, 1st | extension (d) | lumbar_extension (d) |
| lumbar_bending | 2nd | bending to the right | lumbar_bending (d) |
| lumbar_rotation | 3rd | axial rotation to the left | lumbar_rotation (d) |
| shoulder_elevation_plane | thorax -> upper arm: Y-X-Y, 1st | 0 abduction, 90 flexion | - |
| shoulder_elevation | 2nd | negative: raising the arm (e) | - |
| shoulder_rotation | 3rd | internal rotation | - |
| arm_flex | thorax -> upper arm: Z-X-Y, 1st | flexion | arm_flex (f) |
| arm_add | 2nd | adduction | arm_add (f) |
| arm_rot | 3rd | internal rotation | arm_rot (f) |
| elbow_flex | upper arm -> forearm: Z-X-Y, 1st | flexion | elbow_flex (g) |

"OpenSim coordinate": the coordinate of OpenSim's gait models (gait2354, gait2392, Rajagopal
2016) that the angle becomes (`diffbody._opensim_coordinates`); an ISB angle carries an OpenSim
coordinate's name only where it has that coordinate's sign: the knee's flexion is ISB's
`knee_flexion`, OpenSim's `knee_angle` is its negative. "-": the gait models have none. How the
coordinates differ besides the sign:

(a) The same Z-X-Y sequence between the model's pelvis and femur frames, whose neutral is
    not our standing one: expect offsets of a few degrees (the shipped walk's hip flexion:
    3-5 degrees, mostly the pelvis's tilt, tests/mocap/test_mocap.py).
(b) OpenSim's knee_angle is negative in flexion, about one axis (the femur's Z) with a centre
    that moves with the angle (gait2354/2392's spline translations, Rajagopal's coupled
    ones); the gait models have no knee adduction or rotation.
(c) OpenSim's ankle (talocrural) axis is oblique (Inman's, (-0.105, -0.174, 0.979) in the
    tibia's frame), so its angle mixes in some inversion and rotation; its subtalar_angle
    (inversion +) is the subtalar joint alone, about another oblique axis.
(d) Right-handed about the pelvis's Z, extension is positive (ISB's flexion is its
    negative), as OpenSim's lumbar_extension; gait2354's torso is one rigid body from L5-S1
    up, our thorax the frame after the whole spine, so the neutral differs.
(e) Wu 2005 (the thorax-humerus JCS): elevation is a negative turn about the floating axis.
(f) Rajagopal's acromial joint is this Z-X-Y sequence, torso -> humerus; gait2354 has no arms.
(g) Rajagopal's elbow axis is oblique (the carrying angle).

The lumbar angles have no side suffix.

The shoulder's Y-X-Y sequence (Wu 2005) is singular at zero elevation, where the standard
position puts the arm: only the sum of the plane of elevation and the axial rotation is
defined. Safe formulation: where sin(elevation)^2 is below the dtype's epsilon (the
elevation within 1.5e-8 rad in float64, 3.5e-4 rad in float32: rounding alone leaves more
than epsilon squared in a standing body's frames) the plane of elevation is 0 and the axial
rotation takes the whole turn about Y; elsewhere the closed form. Both branches are
evaluated on harmless inputs (the "double where"), so every derivative is finite
everywhere; at the apex itself the elevation, a cone's apex (|b|), reports the subgradient
0. Close to the apex the plane of elevation is ill-conditioned, as it is in the ISB's
definition. The Z-X-Y sequences are singular only at a
second angle of +-90 degrees (hip adduction, knee adduction, ankle inversion, lumbar
bending, arm adduction), outside the joints' ranges.
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._body import Body, Pose
from ._kinematics import forward
from ._rotations import safe_atan2, safe_norm

# Columns: the ISB axes (X anterior, Y superior, Z right) in diffbody's world (X forward,
# Y left, Z up).
R_WORLD_ISB = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
# The mirror image in the sagittal plane, in ISB axes: the left side's joints read as the
# right side's (Wu 2002).
MIRROR_ISB = np.diag([1.0, 1.0, -1.0])
SIDES = (("r", "right"), ("l", "left"))
THORAX_NAMES = ("thorax", "chest")

# (prefix, proximal, distal, sequence, angle names, signs) per limb joint; "{side}" is filled
# with "right" or "left", and "parent:{seg}" is the segment `seg` hangs from.
LIMB_JOINTS: tuple[tuple[str, str, str, str, tuple[str, ...], tuple[float, ...]], ...] = (
    (
        "hip",
        "parent:{side}_thigh",
        "{side}_thigh",
        "zxy",
        ("hip_flexion", "hip_adduction", "hip_rotation"),
        (1.0, 1.0, 1.0),
    ),
    (
        "knee",
        "{side}_thigh",
        "{side}_shank",
        "zxy",
        ("knee_flexion", "knee_adduction", "knee_rotation"),
        (-1.0, 1.0, 1.0),
    ),
    (
        "ankle",
        "{side}_shank",
        "{side}_foot",
        "zxy",
        ("ankle_angle", "ankle_inversion", "ankle_rotation"),
        (1.0, 1.0, 1.0),
    ),
    (
        "shoulder",
        "thorax",
        "{side}_upper_arm",
        "yxy",
        ("shoulder_elevation_plane", "shoulder_elevation", "shoulder_rotation"),
        (1.0, 1.0, 1.0),
    ),
    (
        "arm",
        "thorax",
        "{side}_upper_arm",
        "zxy",
        ("arm_flex", "arm_add", "arm_rot"),
        (1.0, 1.0, 1.0),
    ),
    ("elbow", "{side}_upper_arm", "{side}_forearm", "zxy", ("elbow_flex",), (1.0,)),
)
LUMBAR_NAMES = ("lumbar_extension", "lumbar_bending", "lumbar_rotation")


def angle_names() -> tuple[str, ...]:
    """The keys of `joint_angles`' result, in its order."""
    names = []
    for _, _, _, _, joint_names, _ in LIMB_JOINTS:
        for suffix, _ in SIDES:
            names += [f"{n}_{suffix}" for n in joint_names]
    return tuple(names) + LUMBAR_NAMES


def thorax_segment(body: Body) -> int:
    """The segment whose frame is the ISB thorax: "thorax" or "chest" when the body has one,
    else the segment the right clavicle hangs from (T1 in the default bodies)."""
    for name in THORAX_NAMES:
        if name in body.segment_names:
            return body.segment_index(name)
    return body.parent[body.segment_index("right_clavicle")]


def _segment(body: Body, spec: str, side: str) -> int:
    if spec == "thorax":
        return thorax_segment(body)
    name = spec.format(side=side)
    if name.startswith("parent:"):
        return body.parent[body.segment_index(name[len("parent:") :])]
    return body.segment_index(name)


def cardan_zxy(R: Float[Array, "3 3"]) -> Float[Array, "3"]:
    """(a, b, c) with R = Rz(a) Rx(b) Ry(c), b in [-pi/2, pi/2] (rad); finite derivatives
    also at b = +-pi/2, where a and c are not defined (there c is 0)."""
    b = jnp.arctan2(R[2, 1], safe_norm(jnp.stack([R[0, 1], R[1, 1]])))
    a = safe_atan2(-R[0, 1], R[1, 1])
    c = safe_atan2(-R[2, 0], R[2, 2])
    return jnp.stack([a, b, c])


def euler_yxy(R: Float[Array, "3 3"]) -> Float[Array, "3"]:
    """(a, b, c) with R = Ry(a) Rx(b) Ry(c), b in [-pi, 0] (rad; the ISB's negative
    elevation). Where sin(b)^2 < the dtype's epsilon (b = 0 or -pi within rounding, the
    gimbal lock) a is 0 and c the whole turn about Y; finite derivatives everywhere (module
    docstring)."""
    sq = R[0, 1] ** 2 + R[2, 1] ** 2  # sin(b)^2
    lock = sq <= jnp.finfo(R.dtype).eps
    s = jnp.sqrt(jnp.where(lock, 1.0, sq))
    b = jnp.where(lock, -jnp.arctan2(jnp.zeros_like(R[1, 1]), R[1, 1]), -jnp.arctan2(s, R[1, 1]))
    # Off the lock sin(b) = -s: a = atan2(R01 / sin b, R21 / sin b), c = atan2(R10 / sin b,
    # -R12 / sin b). On it the turn about Y is read off R = Ry(a + c) (b = 0).
    safe = jnp.where(lock, -jnp.ones_like(R), R)
    a = jnp.where(lock, 0.0, jnp.arctan2(-safe[0, 1], -safe[2, 1]))
    c = jnp.where(lock, safe_atan2(R[0, 2], R[0, 0]), jnp.arctan2(-safe[1, 0], safe[1, 2]))
    return jnp.stack([a, b, c])


def anatomical_frames(body: Body, pose: Pose) -> Float[Array, "n_seg 3 3"]:
    """Every segment's ISB anatomical frame in the world, R_world_anatomical: its twisted
    cross of axes turned by the fixed rotation that makes it X forward, Y up, Z right in
    the standard position (module docstring)."""
    return anatomical_of_twisted(body, forward(body, pose).R_world_twisted)


def anatomical_of_twisted(
    body: Body, R_world_twisted: Float[Array, "n_seg 3 3"]
) -> Float[Array, "n_seg 3 3"]:
    """`anatomical_frames` from the twisted frames of `forward`."""
    R_world_rest = forward(body, body.rest_pose()).R_world_twisted
    R_segment_anatomical = jnp.swapaxes(R_world_rest, -1, -2) @ jnp.asarray(
        R_WORLD_ISB, R_world_rest.dtype
    )
    return R_world_twisted @ R_segment_anatomical


def joint_angles(body: Body, pose: Pose) -> dict[str, Float[Array, ""]]:
    """The ISB joint angles of a pose, in degrees (module docstring: frames, sequences,
    signs, names, and the OpenSim coordinate each becomes).

    Pure JAX: compose it under jax.jit / jax.vmap / jax.grad (batching is jax.vmap over
    poses). Derivatives are finite everywhere, the standard position included.

    Args:
        body: a body with the default bodies' limbs (pelvis, thighs, shanks, feet, clavicles,
            upper arms, forearms) and a thorax (`thorax_segment`).
        pose: one pose; a Bendspine `spine_target` bends the spine, and the thorax with it.

    Returns:
        name -> angle (degrees, a scalar) for every name of `angle_names()` (a dict
        through jax.jit comes back with its keys sorted).
    """
    return angles_of_frames(body, anatomical_frames(body, pose))


def angles_of_frames(body: Body, R: Float[Array, "n_seg 3 3"]) -> dict[str, Float[Array, ""]]:
    """`joint_angles` from every segment's anatomical frame (`anatomical_frames`)."""
    mirror = jnp.asarray(MIRROR_ISB, R.dtype)
    out: dict[str, Array] = {}
    for _, proximal, distal, sequence, names, signs in LIMB_JOINTS:
        decompose = cardan_zxy if sequence == "zxy" else euler_yxy
        for suffix, side in SIDES:
            p, d = _segment(body, proximal, side), _segment(body, distal, side)
            R_proximal_distal = R[p].T @ R[d]
            if side == "left":
                R_proximal_distal = mirror @ R_proximal_distal @ mirror
            angles = jnp.degrees(decompose(R_proximal_distal))
            for k, (name, sign) in enumerate(zip(names, signs)):
                out[f"{name}_{suffix}"] = sign * angles[k]
    pelvis, thorax = body.segment_index("pelvis"), thorax_segment(body)
    lumbar = jnp.degrees(cardan_zxy(R[pelvis].T @ R[thorax]))
    for k, name in enumerate(LUMBAR_NAMES):
        out[name] = lumbar[k]
    return out
