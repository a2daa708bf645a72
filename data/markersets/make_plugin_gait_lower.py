"""Write `plugin-gait-lower.json`: Vicon's Plug-in Gait lower-body markers on diffbody's
default body, placed from the protocol's written placement rules (data/markersets/README.md),
and print where each lands and the distances between them. Run from the repository root:

    python data/markersets/make_plugin_gait_lower.py

Most markers are `sphere_surface` placements: a ray from the segment's axis to the outermost
skin, so they sit on the skin of any body the set is resolved for. Three positions need a
computation on the default body and are written as numbers:
- the ASIS, from Plug-in Gait's own hip joint centre model (Davis et al. 1991, as Vicon's
  Plug-in Gait reference guide gives it) turned around: the ASIS relative to the hip joints;
- the PSIS rays start at the ASIS's height on the pelvis axis (Plug-in Gait's pelvis frame
  is then the standard axes in the standard position);
- the TOE over the ball of the foot, on the top of the foot's spheres (a ray from the foot's
  axis, which runs at the ankle's height, cannot reach the low dorsum there), and the HEE
  ray's downward tilt that puts the heel marker at the TOE's height.
"""

import json
import math
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import diffbody as db  # noqa: E402
from diffbody._body import rest_geometry  # noqa: E402
from diffbody.files._markerset_file import (  # noqa: E402
    DEFAULT_MARKER_RADIUS,
    MarkerEntry,
    resolve_offset,
)

HERE = Path(__file__).parent
OUT = HERE / "plugin-gait-lower.json"

# Davis RB, Ounpuu S, Tyburski D, Gage JR (1991), as Vicon's Plug-in Gait reference guide
# gives it: C = 0.115 LegLength - 15.3 mm, AsisTrocDist = 0.1288 LegLength - 48.56 mm,
# theta = 0.5 rad, beta = 0.314 rad. In the pelvis frame (origin the ASIS markers' midpoint,
# X forward, Y left, Z up) the hip joint centre is
#   X = C cos(theta) sin(beta) - (AsisTrocDist + r) cos(beta)
#   Y = +-(aa - C sin(theta))           (aa: half the ASIS markers' distance)
#   Z = -C cos(theta) cos(beta) - (AsisTrocDist + r) sin(beta)
# with r the marker radius. Turned around: the ASIS marker lies -X forward, -Z up and
# C sin(theta) lateral of the hip joint centre.
THETA, BETA = 0.5, 0.314
# Thigh and tibia markers: in the lower third of the segment (Plug-in Gait), 0.7 of the
# way from the proximal joint (the default body's fingertips hang at 0.63 of the thigh).
LOWER_THIRD = 0.7
# The ball of the foot: ANSUR II's ball-of-foot length over foot length, 0.741 (men) and
# 0.739 (women) at the median (data/ansur2_percentiles.csv).
BALL = 0.74
# m between the PSIS markers: a modelling choice (no source of the default body gives the
# PSIS); a ray from the pelvis axis straight back puts both on the midline.
PSIS_APART = 0.09

SOURCES = [
    "Vicon Motion Systems, Plug-in Gait Reference Guide (Vicon Nexus documentation): "
    "lower-body marker placement (LASI/RASI, LPSI/RPSI or SACR, LTHI/RTHI, LKNE/RKNE, "
    "LTIB/RTIB, LANK/RANK, LHEE/RHEE, LTOE/RTOE) and the hip joint centre model",
    "Davis RB, Ounpuu S, Tyburski D, Gage JR, 1991, A gait analysis data collection and "
    "reduction technique, Human Movement Science 10(5):575-587",
    "Kadaba MP, Ramakrishnan HK, Wootten ME, 1990, Measurement of lower extremity "
    "kinematics during level walking, J Orthop Res 8(3):383-392",
]


def asis_offset(leg_length: float, r: float) -> np.ndarray:
    """The left ASIS marker (m, standard axes) from the hip joints' midpoint, for a leg
    length in m and a marker radius r in m (Davis's model turned around, above), with
    the default body's hips 2 hw apart: hw + C sin(theta) lateral."""
    C = 0.115 * leg_length - 0.0153
    troc = 0.1288 * leg_length - 0.04856
    forward = (troc + r) * math.cos(BETA) - C * math.cos(THETA) * math.sin(BETA)
    up = C * math.cos(THETA) * math.cos(BETA) + (troc + r) * math.sin(BETA)
    return np.array([forward, C * math.sin(THETA), up])


def world(body, rest, entry: dict) -> np.ndarray:
    """Where an entry (standard axes) lands on `body` in the standard position, m."""
    seg = body.segment_index(entry["segment"])
    where = MarkerEntry(str(OUT), entry["name"])
    offset = resolve_offset(where, entry, body, rest, seg, "standard", DEFAULT_MARKER_RADIUS)
    joints, _ = rest
    return joints[body.proximal_joint[seg]] + np.asarray(body.R_socket_rest[seg]) @ offset


def _entry(name, segment, kind, tolerance, description, **placement) -> dict:
    return {"name": name, "segment": segment, **placement, "kind": kind,
            "tolerance": tolerance, "weight": 1, "description": description}  # fmt: skip


def _round(v) -> list[float]:
    return [round(float(x), 4) + 0.0 for x in v]  # + 0.0: no "-0.0" in the file


def build(body) -> dict:
    """The set's JSON document for the default body (module docstring)."""
    rest = rest_geometry(body)
    joints, _ = rest
    r = DEFAULT_MARKER_RADIUS
    hw = float(joints[body.joint_index("left_hip"), 1] - joints[body.joint_index("center_hip"), 1])
    # Plug-in Gait's leg length: ASIS to medial malleolus (straight legs: the straight line).
    # The ASIS depends on it: a fixed point, reached in a few steps.
    malleolus = world(
        body, rest, _entry("m", "left_shank", "", 0, "", sphere_surface=[0, -1, 0], along=1.0)
    )
    leg = 0.9
    for _ in range(20):
        a = asis_offset(leg, r) + [0.0, hw, 0.0]
        leg = float(np.linalg.norm(joints[body.joint_index("center_hip")] + a - malleolus))
    asis = asis_offset(leg, r) + [0.0, hw, 0.0]
    pelvis = body.segment_index("pelvis")
    prox, dist = joints[body.proximal_joint[pelvis]], joints[body.distal_joint[pelvis]]
    along = round(float(asis[2] / (dist[2] - prox[2])), 4)  # the pelvis axis at the ASIS's height

    def pelvis_ray(direction):
        e = _entry("p", "pelvis", "", 0, "", sphere_surface=direction, along=along)
        return world(body, rest, e)

    def aim(direction_of, y_target):
        """The k for which the ray direction_of(k) leaves the skin at y = y_target (bisected:
        the exit moves outward as the ray turns outward)."""
        lo, hi = 0.0, 4.0
        for _ in range(60):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if pelvis_ray(direction_of(mid))[1] < y_target else (lo, mid)
        return round((lo + hi) / 2, 3)

    # The ASIS: Davis's height and lateral distance, on the skin of this body's front (his
    # forward distance lies inside the default body's spheres, `main` prints by how much).
    asis_k = aim(lambda k: [1, k, 0], float(asis[1]))
    psis_k = aim(lambda k: [-1, k, 0], PSIS_APART / 2)

    foot = body.segment_index("left_foot")
    foot_length = float(body.lengths[foot]) / 0.78  # the toe tip 0.78 foot lengths ahead
    ball_x = (BALL - 0.22) * foot_length  # from the ankle; the heel's back 0.22 behind
    _, centers = rest
    on_foot = np.flatnonzero(np.asarray(body.sphere_segment) == foot)
    ankle = joints[body.proximal_joint[foot]]
    d = np.array([ball_x, 0.0]) - (centers[on_foot, :2] - ankle[:2])
    reach = np.asarray(body.sphere_radii)[on_foot] ** 2 - np.sum(d**2, axis=1)
    top = np.max(centers[on_foot, 2][reach > 0] + np.sqrt(reach[reach > 0])) + r
    toe = [ball_x, 0.0, top - ankle[2]]  # from the ankle, standard axes

    def heel(tilt):
        return _entry("h", "left_foot", "", 0, "", sphere_surface=[-1, 0, -tilt], along=0.0)

    lo, hi = -1.0, 3.0  # the heel marker's height falls as the ray tilts down: bisect
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if world(body, rest, heel(mid))[2] > top else (lo, mid)
    tilt = round((lo + hi) / 2, 3)

    pelvis_markers, legs = [], []
    for side, s in (("L", 1.0), ("R", -1.0)):
        sd = "left" if s > 0 else "right"
        m = [
            _entry(f"{side}ASI", "pelvis", "anatomical", 0.005,
                   "anterior superior iliac spine: its height above and distance from the hip "
                   "joint by Plug-in Gait's hip joint centre model (Davis 1991) turned around, "
                   "on the skin of the front",
                   sphere_surface=[1, s * asis_k, 0], along=along),
            _entry(f"{side}PSI", "pelvis", "anatomical", 0.01,
                   f"posterior superior iliac spine, on the skin of the back at the ASIS's "
                   f"height (standard position: zero Plug-in Gait pelvic tilt), {PSIS_APART} m "
                   "apart",
                   sphere_surface=[-1, s * psis_k, 0], along=along),
            _entry(f"{side}THI", f"{sd}_thigh", "tracking", 0.03,
                   "lower lateral third of the thigh, in the plane of the hip, the knee and "
                   "the knee marker (its height is not critical)",
                   sphere_surface=[0, s, 0], along=LOWER_THIRD),
            _entry(f"{side}KNE", f"{sd}_thigh", "anatomical", 0.005,
                   "lateral femoral epicondyle, on the knee's flexion axis",
                   sphere_surface=[0, s, 0], along=1.0),
            _entry(f"{side}TIB", f"{sd}_shank", "tracking", 0.03,
                   "lower lateral third of the shank, in the plane of the knee, the ankle "
                   "and the ankle marker (its height is not critical)",
                   sphere_surface=[0, s, 0], along=LOWER_THIRD),
            _entry(f"{side}ANK", f"{sd}_shank", "anatomical", 0.005,
                   "lateral malleolus, on the transmalleolar axis",
                   sphere_surface=[0, s, 0], along=1.0),
            _entry(f"{side}HEE", f"{sd}_foot", "anatomical", 0.005,
                   "calcaneus, at the toe marker's height above the sole",
                   sphere_surface=[-1, 0, -tilt], along=0.0),
            _entry(f"{side}TOE", f"{sd}_foot", "anatomical", 0.005,
                   "second metatarsal head, on the top of the foot over the ball "
                   f"({BALL} foot lengths from the heel), on the midfoot side of the toes' crease",
                   offset=_round(toe)),
        ]  # fmt: skip
        pelvis_markers += m[:2]
        legs += m[2:]
    # LASI, RASI, LPSI, RPSI, then the left leg's markers and the right's.
    markers = sorted(pelvis_markers, key=lambda e: e["name"][1:] == "PSI") + legs
    on_skin = pelvis_ray([1, asis_k, 0]) - joints[body.joint_index("center_hip")]
    print(
        f"leg length {leg:.4f} m; Davis's ASIS from the hips' midpoint {np.round(asis, 4)}, "
        f"on the skin {np.round(on_skin, 4)}"
    )
    print(f"TOE {np.round(toe, 4)} from the ankle (height {top:.4f} m), HEE tilt {tilt}")
    return {
        "schema": "diffbody.markerset/1",
        "name": "plugin-gait-lower",
        "description": "Vicon's Plug-in Gait lower-body set (16 markers: LASI, RASI, LPSI, "
        "RPSI, and LTHI, LKNE, LTIB, LANK, LHEE, LTOE and their right twins), placed on the "
        "default body from the protocol's written placement rules; no recorded Plug-in Gait "
        "trial checks it (data/markersets/README.md). Written by make_plugin_gait_lower.py.",
        "sources": SOURCES,
        "axes": "standard",
        "marker_radius": DEFAULT_MARKER_RADIUS,
        "markers": markers,
    }


def write(doc: dict, path: Path = OUT) -> None:
    """One marker a line, as the shipped sets are written."""
    lines = ",\n".join("    " + json.dumps(m) for m in doc["markers"])
    head = {k: v for k, v in doc.items() if k != "markers"}
    text = json.dumps(head, indent=2)[:-2] + ',\n  "markers": [\n' + lines + "\n  ]\n}\n"
    path.write_text(text, encoding="utf-8")


def check(body) -> None:
    """Where the markers land (standard position) and the distances between them."""
    markers = db.load_markerset(str(OUT), body)
    rest = rest_geometry(body)
    joints, centers = rest
    seg = np.asarray(markers.segments)
    R = np.asarray(body.R_socket_rest)[seg]
    p = joints[np.asarray(body.proximal_joint)[seg]]
    p = p + np.einsum("kij,kj->ki", R, np.asarray(markers.offsets))
    gap = np.linalg.norm(p[:, None] - centers[None], axis=-1) - np.asarray(body.sphere_radii)
    at = dict(zip(markers.names, p))
    print("marker   world (m), standard position      skin to marker centre (mm)")
    for name, q, g in zip(markers.names, p, gap.min(axis=1)):
        print(f"{name:6s} {np.round(q, 3)!s:32s} {1000 * g:5.1f}")
    print("distance         m")
    for a, b in [("LASI", "RASI"), ("LPSI", "RPSI"), ("LASI", "LPSI"), ("LASI", "LKNE"),
                 ("LKNE", "LANK"), ("LHEE", "LTOE"), ("LKNE", "RKNE")]:  # fmt: skip
        print(f"{a + ' - ' + b:14s} {np.linalg.norm(at[a] - at[b]):.3f}")


def main() -> None:
    body = db.load_body()
    write(build(body))
    check(body)


if __name__ == "__main__":
    main()
