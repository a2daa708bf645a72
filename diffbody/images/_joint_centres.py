"""Joint centres of the default joint tree from the markers of a motion-capture trial: the
"semi-real" sequences of image-sequence analysis (real motion, a synthetic camera;
docs/design.md, section 8). Positions (frames, 15, 3) in m, world frame.

Standard approximations or documented stand-ins (the walking trial of data/mocap has no
markers on the joint centres): hips by Harrington et al. (2007) (`hip_centres`), knees and
ankles from the static trial's medial and lateral markers carried into the walk by the thigh
and shank clusters (Cappozzo et al. 1995; the knee the mean of both clusters'), shoulders and
elbows at their markers (the acromion marker sits some 4-5 cm above the joint), wrists between
their two markers, ``C7_T1`` between the acromions, ``head.top`` at the head-top marker. The
distances between these points are not rigid; a benchmark takes each part's median length.
"""

import numpy as np

from ._joint_tree import DEFAULT_JOINTS

NAMES = tuple(name for name, _ in DEFAULT_JOINTS)


def _frame(p1: np.ndarray, p2: np.ndarray, p3: np.ndarray) -> np.ndarray:
    """Rotation (..., 3, 3) whose columns are a right-handed frame of three markers: x from
    p1 to p2, z normal to their plane."""
    x = p2 - p1
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    z = np.cross(x, p3 - p1)
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def _in_cluster(trial, static, cluster: tuple[str, str, str], landmarks: tuple[str, str]):
    """(T, 3) the midpoint of `landmarks` (seen in the static trial) in every frame of
    `trial`, carried rigidly by the three `cluster` markers."""
    s = static.mean_frame()
    c0 = [s.marker(n)[0] for n in cluster]
    target = np.mean([s.marker(n)[0] for n in landmarks], axis=0)
    local = _frame(*c0).T @ (target - c0[0])
    c = [trial.marker(n) for n in cluster]
    return c[0] + np.einsum("tij,j->ti", _frame(*c), local)


def hip_centres(trial) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) hip joint centres (T, 3) m by Harrington et al. (2007), in the pelvis
    frame (origin mid-ASIS, x anterior, y superior, z right): x = -0.24 PD - 9.9 mm,
    y = -0.30 PW - 10.9 mm, z = +-(0.33 PW + 7.3 mm), PW the inter-ASIS distance, PD from
    mid-ASIS to the sacral marker (standing for mid-PSIS)."""
    r, lft, sac = trial.marker("R.ASIS"), trial.marker("L.ASIS"), trial.marker("V.Sacral")
    origin = (r + lft) / 2
    z = (r - lft) / np.linalg.norm(r - lft, axis=-1, keepdims=True)
    x = origin - sac
    x = x - np.sum(x * z, -1, keepdims=True) * z
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(z, x)
    pw = np.linalg.norm(r - lft, axis=-1, keepdims=True) * 1e3  # mm
    pd = np.linalg.norm(origin - sac, axis=-1, keepdims=True) * 1e3
    ax, ay, az = -0.24 * pd - 9.9, -0.30 * pw - 10.9, 0.33 * pw + 7.3
    right = origin + 1e-3 * (ax * x + ay * y + az * z)
    left = origin + 1e-3 * (ax * x + ay * y - az * z)
    return left, right


def joint_centres_from_markers(trial, static) -> np.ndarray:
    """The default joint tree's joints (T, 15, 3) m, world frame, in `NAMES` order, from a
    walking `MarkerTrial` and the static trial that calibrates its knees and ankles (module
    docstring). Raises KeyError naming a missing marker."""
    left_hip, right_hip = hip_centres(trial)
    out = {"center_hip": (left_hip + right_hip) / 2, "left_hip": left_hip, "right_hip": right_hip}
    for side, s in (("left", "L"), ("right", "R")):
        thigh = tuple(f"{s}.Thigh.{m}" for m in ("Upper", "Front", "Rear"))
        shank = tuple(f"{s}.Shank.{m}" for m in ("Upper", "Front", "Rear"))
        knee_marks = (f"{s}.Knee.Lat", f"{s}.Knee.Med")
        out[f"{side}_knee"] = (
            _in_cluster(trial, static, thigh, knee_marks)
            + _in_cluster(trial, static, shank, knee_marks)
        ) / 2
        out[f"{side}_ankle"] = _in_cluster(
            trial, static, shank, (f"{s}.Ankle.Lat", f"{s}.Ankle.Med")
        )
        out[f"{side}_shoulder"] = trial.marker(f"{s}.Acromium")
        out[f"{side}_elbow"] = trial.marker(f"{s}.Elbow")
        out[f"{side}_wrist"] = (trial.marker(f"{s}.Wrist.Med") + trial.marker(f"{s}.Wrist.Lat")) / 2
    out["C7_T1"] = (trial.marker("L.Acromium") + trial.marker("R.Acromium")) / 2
    out["head.top"] = trial.marker("Top.Head")
    return np.stack([out[n] for n in NAMES], axis=1)


def load_walk_joints() -> tuple[np.ndarray, np.ndarray]:
    """(times (151,) s, joints (151, 15, 3) m, world frame) of the OpenSim example walk, as
    `joint_centres_from_markers` gives them, from data/webb/walk1_joints.csv (no marker
    files needed)."""
    from ..files._data_files import data_array

    data = data_array("webb/walk1_joints.csv", header_lines=3)
    return data[:, 1], data[:, 2:].reshape(len(data), len(NAMES), 3)
