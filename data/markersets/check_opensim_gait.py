"""Check the placement of `opensim-gait.json` against the static trial it was made for.

Prints, for every marker, where the default body puts it and where the subject's static trial
has it (its mean over the 300 frames, turned so that the pelvis faces +X and moved so that the
ASIS midpoints coincide horizontally), and the distances between markers that scale the body.
The body is the default male50 with its lengths scaled by the subject's stature over its own
(1.803 m / 1.755 m), in the standard position with the arms raised sideways to the horizontal,
as the subject holds them. Run from the repository root:

    python data/markersets/check_opensim_gait.py
"""

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import diffbody as db  # noqa: E402
from diffbody.files._data_files import data_file  # noqa: E402
from diffbody.files._markerset_file import load_markerset  # noqa: E402
from diffbody.files._trc import read_trc  # noqa: E402
from diffbody.mocap._markerset import scale_offsets, world_markers  # noqa: E402

SUBJECT_STATURE = 1.8034  # m, OpenSim's scale setup (subject01_Setup_Scale.xml)
ARMS = ("Acromium", "Bicep", "Elbow", "Wrist")
PAIRS = [
    ("R.ASIS", "L.ASIS"),
    ("R.ASIS", "V.Sacral"),
    ("R.ASIS", "R.Knee.Lat"),
    ("L.ASIS", "L.Knee.Lat"),
    ("R.Knee.Lat", "R.Knee.Med"),
    ("R.Knee.Lat", "R.Ankle.Lat"),
    ("L.Knee.Lat", "L.Ankle.Lat"),
    ("R.Ankle.Lat", "R.Ankle.Med"),
    ("R.Heel", "R.Toe.Tip"),
    ("L.Heel", "L.Toe.Tip"),
    ("R.Toe.Lat", "R.Toe.Med"),
    ("R.Acromium", "L.Acromium"),
    ("R.Acromium", "R.Elbow"),
    ("R.Elbow", "R.Wrist.Lat"),
    ("R.Wrist.Lat", "R.Wrist.Med"),
    ("R.Temple", "L.Temple"),
    ("Sternum", "Top.Head"),
]


def model_markers() -> dict[str, np.ndarray]:
    body = db.load_body()
    markers = load_markerset("opensim-gait", body)
    k = SUBJECT_STATURE / float(db.measure(body, ["stature"])[0])
    axial, radial = jnp.full(body.n_segments, k), jnp.ones(body.n_segments)
    scaled = db.scale_body(body, axial, radial)
    pose = scaled.rest_pose()
    angles = pose.angles
    for side, theta in (("left", np.pi / 2), ("right", -np.pi / 2)):  # arms out sideways
        i = scaled.segment_index(f"{side}_upper_arm")
        angles = angles.at[i, :2].set(jnp.array([theta, np.pi / 2]))
    pose = db.Pose(position=pose.position, angles=angles)
    p = np.asarray(world_markers(scaled, pose, scale_offsets(markers, body, axial, radial)))
    mid = (p[markers.index("R.ASIS")] + p[markers.index("L.ASIS")]) / 2
    return {n: q - [mid[0], mid[1], 0.0] for n, q in zip(markers.names, p)}


def trial_markers() -> dict[str, np.ndarray]:
    static = read_trc(data_file("mocap/subject01_static.trc")).mean_frame()
    p = dict(zip(static.names, static.positions[0]))
    mid = (p["R.ASIS"] + p["L.ASIS"]) / 2
    forward = mid - p["V.Sacral"]
    forward[2] = 0.0
    forward /= np.linalg.norm(forward)
    left = np.cross([0.0, 0.0, 1.0], forward)
    return {n: np.array([(q - mid) @ forward, (q - mid) @ left, q[2]]) for n, q in p.items()}


def main() -> None:
    model, trial = model_markers(), trial_markers()
    print("marker          body - trial (cm): forward   left     up    | trial (m)")
    heights = []
    for name, p in model.items():
        d = (p - trial[name]) * 100
        heights.append(d[2])
        print(f"{name:15s} {d[0]:24.1f} {d[1]:6.1f} {d[2]:6.1f}    | {np.round(trial[name], 3)}")
    legs = [h for n, h in zip(model, heights) if not any(a in n for a in ARMS)]
    print(
        f"height differences: all {np.mean(heights):.1f} cm mean, {np.max(np.abs(heights)):.1f} "
        f"max; without the arms {np.mean(legs):.1f} mean, {np.max(np.abs(legs)):.1f} max"
    )
    print("distance                      trial    body   (m)")
    for a, b in PAIRS:
        d_trial = np.linalg.norm(trial[a] - trial[b])
        d_body = np.linalg.norm(model[a] - model[b])
        change = 100 * (d_body - d_trial)
        print(f"{a + ' - ' + b:28s} {d_trial:6.3f}  {d_body:6.3f}  {change:+5.1f} cm")


if __name__ == "__main__":
    main()
