"""Where an OpenSim model's pelvis and torso frames lie in our anatomical frames, found from
where the model's markers and ours sit on each bone (`model_frames`), so that the coordinates
written for that model read as its own (docs/design.md, section 7, "OpenSim's coordinates")."""

import numpy as np

from .._body import Body, rest_geometry
from .._joint_angles import R_WORLD_ISB
from .._opensim_coordinates import ModelFrames
from ..files._markerset_file import MarkerSet
from ._markerset import world_markers

# The model's bodies whose frames `ModelFrames` holds (OpenSim's names); ours are the pelvis and the
# thorax, whose anatomical frames are the ISB axes in the standard position.
MODEL_BODIES = ("pelvis", "torso")


def rigid_fit(P: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) with Q ~ R P + t in least squares, R a rotation (Kabsch): P, Q (n, 3)."""
    p, q = P.mean(0), Q.mean(0)
    U, _, Vt = np.linalg.svd((Q - q).T @ (P - p))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return R, q - R @ p


def model_frames(
    body: Body, markerset: MarkerSet, model_markers: dict[str, tuple[str, np.ndarray]]
) -> ModelFrames:
    """The model's pelvis and torso frames, and its pelvis origin, in our anatomical frames.

    In the standard position our anatomical frames are the ISB axes; there our markers
    (`markerset` on `body`: a registered set carries the subject's offsets) and the model's
    (`model_markers`: `diffbody.files.read_model_markers` of its .osim or marker set) are
    the same landmarks, so the rigid fit of the model's markers on a bone onto ours is the
    model's frame of that bone in ours. A bone needs three of the set's markers; one with
    fewer is a ValueError naming it.
    """
    rest = body.rest_pose()
    ours = np.asarray(world_markers(body, rest, markerset), float) @ R_WORLD_ISB
    found = {}
    for bone in MODEL_BODIES:
        names = [n for n, (b, _) in model_markers.items() if b == bone and n in markerset.names]
        if len(names) < 3:
            raise ValueError(
                f"model_frames: the model's {bone} carries {len(names)} of the marker set's "
                f"markers ({', '.join(names) or 'none'}); three are needed to place its frame"
            )
        P = np.array([model_markers[n][1] for n in names])
        Q = np.array([ours[markerset.index(n)] for n in names])
        found[bone] = rigid_fit(P, Q)
    joints = np.asarray(rest_geometry(body)[0], float) @ R_WORLD_ISB
    hips = joints[[body.joint_index("right_hip"), body.joint_index("left_hip")]].mean(0)
    (R_pelvis, t_pelvis), (R_torso, _) = found["pelvis"], found["torso"]
    dtype = body.lengths.dtype
    return ModelFrames(
        R_pelvis=np.asarray(R_pelvis, dtype),
        R_torso=np.asarray(R_torso, dtype),
        pelvis_origin=np.asarray(t_pelvis - hips, dtype),
    )
