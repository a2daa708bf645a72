"""Build the default sphere-skinned bodies data/body_male50.json and data/body_female50.json.

Usage::

    python data/build_bodies.py

Reads only ``data/ansur2_percentiles.csv`` (written by ``data/derive_ansur2.py``); the de Leva
segment parameters, the joint ranges of motion and the spine tables are constants below, each
with its citation (copied from ../shared/reference/REFERENCE.md). The output follows
``data/SCHEMA.md`` (``diffbody.body/1``). Every modelling choice is listed in
``data/README.md``. The script is deterministic: running it twice writes identical files.

Conventions (SCHEMA.md): world X forward, Y left, Z up, metres, kilograms, degrees. A
segment's cross of axes has +Z along its direction, +X in the world XZ-plane with a positive
forward component (up if Z is +-world X, forward if Z is +-world Y), +Y = Z x X. Sphere
origins and feature directions are written in that frame.
"""

from __future__ import annotations

import csv
import json
import math
import pathlib

import numpy as np

DATA = pathlib.Path(__file__).resolve().parent
PERCENTILES = DATA / "ansur2_percentiles.csv"

SCHEMA = "diffbody.body/1"

# --------------------------------------------------------------------------------------
# Citations
# --------------------------------------------------------------------------------------

CITE_ANSUR = (
    'Gordon CC, Blackwell CL, Bradtmiller B, et al., 2014, "2012 Anthropometric Survey of '
    'U.S. Army Personnel: Methods and Summary Statistics", NATICK/TR-15/007; public data '
    "release; P50 (unweighted sample median) from data/ansur2_percentiles.csv"
)
CITE_DELEVA = (
    "de Leva P, 1996, Adjustments to Zatsiorsky-Seluyanov's segment inertia parameters, "
    "J Biomech 29(9):1223-1230, Table 4 (as transcribed by BMClab/BMC and Gurchiek 2018)"
)
CITE_WP = (
    "White AA, Panjabi MM, 1990, Clinical Biomechanics of the Spine, 2nd ed. (segmental ROM "
    "table, representative values as commonly reproduced; not confirmed against the book)"
)
CITE_WP_1B = (
    "White AA, Panjabi MM, 1990, Clinical Biomechanics of the Spine, 2nd ed., Table 2-1, "
    "as transcribed in a GitHub build_spine.py (C7-T1 representative values only)"
)
CITE_NORKIN = (
    "Norkin CC, White DJ, Measurement of Joint Motion: A Guide to Goniometry (F.A. Davis), "
    "Appendix Table A.1 (AAOS, AMA and Boone & Azen columns)"
)
CITE_BOONE = (
    "Boone DC, Azen SP, 1979, Normal range of motion of joints in male subjects, "
    "J Bone Joint Surg Am 61(5):756-759"
)
CITE_MERCK = (
    "Merck Manual (Professional), Normal Values for Range of Motion of Joints, Table 1, "
    "(c) 2010-2013 Merck Sharp & Dohme"
)
CITE_VA = (
    "U.S. VA rating schedule 38 CFR 4.71 Plates I-II as reproduced in a 'Normal-ROM' "
    "document (not checked against the CFR)"
)
CITE_EXRX = "exrx.net (secondary web page): neck lateral flexion 45, rotation 60-80 (not confirmed)"
CITE_FLETCHER = (
    "Fletcher JGR, Stringer MD, Briggs CA, Davies TM, Woodley SJ, 2015, CT morphometry of "
    "adult thoracic intervertebral discs, Eur Spine J, doi 10.1007/s00586-015-3925-y"
)
CITE_EGWU = (
    "Egwu OA et al., 2019, Typical thoracic vertebrae morphometry: A cadaveric study in "
    "Nigeria, J Anat Soc India 68(2):110-118"
)
CITE_L5 = (
    "Int J Spine Surg, Table 6 'Measurements at the L5 level' (ijssurgery.com/highwire/"
    "markup/11003; authors and title not captured)"
)
CITE_MRI_DISC = (
    "Measuring Dimensions of Lumbar Intervertebral Discs in Normal Subjects, Anatomical "
    "Sciences Journal (anatomyjournal.ir, A-10-159-1; authors and year not captured)"
)
CITE_DEMPSTER = (
    "Winter DA, 2009, Biomechanics and Motor Control of Human Movement, 4th ed., Table 4.1, "
    "after Dempster WT, 1955, Space requirements of the seated operator, WADC-TR-55-159 "
    "(head+neck segment ends at the ear canal)"
)
CITE_BADLER = (
    "Badler NI, O'Rourke J, 1979, Representation of Articulate, Quasi-Rigid, "
    "Three-Dimensional Objects, Univ. of Pennsylvania MS-CIS-79-24 (standard position, "
    "cross of axes, sphere surface)"
)
CITE_MONHEIT = (
    "Monheit G, Badler NI, 1991, A Kinematic Model of the Human Spine and Torso, IEEE "
    "Computer Graphics and Applications 11(2):29-38 (17 vertebrae T1-L5, torso slices)"
)

SOURCES = [
    CITE_BADLER,
    CITE_MONHEIT,
    CITE_ANSUR,
    CITE_DELEVA,
    CITE_DEMPSTER,
    CITE_WP,
    CITE_WP_1B,
    CITE_EGWU,
    CITE_L5,
    CITE_FLETCHER,
    CITE_MRI_DISC,
    CITE_NORKIN,
    CITE_BOONE,
    CITE_MERCK,
    CITE_VA,
    CITE_EXRX,
]

# --------------------------------------------------------------------------------------
# de Leva 1996, Table 4 (REFERENCE.md section 3a), status V(S).
# row: (female, male) pairs of (length mm, mass % of body mass, CM % of length from the
# first-listed endpoint). Reference subjects: male 1741 mm / 73.0 kg, female 1735 mm / 61.9 kg.
# CM is from the proximal endpoint except Head (from the vertex) and Foot (from the heel).
# --------------------------------------------------------------------------------------

DELEVA_STATURE_MM = {"female": 1735.0, "male": 1741.0}
DELEVA = {
    # segment row: {"female": (length_mm, mass_pct, cm_pct), "male": (...)}
    "head_VERT_CERV": {"female": (243.7, 6.68, 48.41), "male": (242.9, 6.94, 50.02)},
    "upper_trunk_CERV_XYPH": {"female": (228.0, 15.45, 50.50), "male": (242.1, 15.96, 50.66)},
    "middle_trunk_XYPH_OMPH": {"female": (205.3, 14.65, 45.12), "male": (215.5, 16.33, 45.02)},
    "lower_trunk_OMPH_MIDH": {"female": (181.5, 12.47, 49.20), "male": (145.7, 11.17, 61.15)},
    "upper_arm_SJC_EJC": {"female": (275.1, 2.55, 57.54), "male": (281.7, 2.71, 57.72)},
    "forearm_EJC_WJC": {"female": (264.3, 1.38, 45.59), "male": (268.9, 1.62, 45.74)},
    "hand_WJC_DAC3": {"female": (170.1, 0.56, 34.27), "male": (187.9, 0.61, 36.24)},
    "thigh_HJC_KJC": {"female": (368.5, 14.78, 36.12), "male": (422.2, 14.16, 40.95)},
    "shank_KJC_LMAL": {"female": (432.3, 4.81, 44.16), "male": (434.0, 4.33, 44.59)},
    "foot_HEEL_TTIP": {"female": (228.3, 1.29, 40.14), "male": (258.1, 1.37, 44.15)},
}
DELEVA_LABEL = {
    "head_VERT_CERV": "Head (alt.) VERT-CERV",
    "upper_trunk_CERV_XYPH": "Upper trunk (alt.) CERV-XYPH",
    "middle_trunk_XYPH_OMPH": "Middle trunk XYPH-OMPH",
    "lower_trunk_OMPH_MIDH": "Lower trunk OMPH-MIDH",
    "upper_arm_SJC_EJC": "Upper arm SJC-EJC",
    "forearm_EJC_WJC": "Forearm EJC-WJC",
    "hand_WJC_DAC3": "Hand (alt.) WJC-DAC3",
    "thigh_HJC_KJC": "Thigh HJC-KJC",
    "shank_KJC_LMAL": "Shank KJC-LMAL",
    "foot_HEEL_TTIP": "Foot HEEL-TTIP",
}

# --------------------------------------------------------------------------------------
# Spine geometry (REFERENCE.md section 2), used only for the proportions of the column.
# --------------------------------------------------------------------------------------

VERTEBRAE = [f"T{i}" for i in range(1, 13)] + [f"L{i}" for i in range(1, 6)]


def _vertebral_body_heights_mm() -> dict[str, float]:
    """Mean of anterior and posterior body height per vertebra (mm).

    T2 (16.93+17.59)/2 and T9 (18.83+20.46)/2: Egwu et al. 2019 (REFERENCE 2a, V); linear in
    between and extrapolated to T1 and T10-T12 with the same slope (modelling choice).
    L5 (30.3+26.3)/2: Int J Spine Surg Table 6 (REFERENCE 2a, V). L1 = 25.0 mm is a
    modelling choice (no lumbar per-level figure in the references); L1-L5 linear.
    """
    t2 = (16.93 + 17.59) / 2.0
    t9 = (18.83 + 20.46) / 2.0
    slope = (t9 - t2) / 7.0
    heights = {f"T{i}": t2 + slope * (i - 2) for i in range(1, 13)}
    l1, l5 = 25.0, (30.3 + 26.3) / 2.0
    heights.update({f"L{i}": l1 + (l5 - l1) * (i - 1) / 4.0 for i in range(1, 6)})
    return heights


# Disc heights per level (mm), C7-T1 ... L5-S1 (18 joints).
# Thoracic: anterior heights of Fletcher et al. 2015 (REFERENCE 2b, V): T4-5 2.7, T10-11 5.4,
# linear in between and extrapolated to T11-12; T2-3 and T1-2 taken as 3.0 ("T4-5 is similar
# to or smaller than T2-3"), T3-4 between; the mean of T2-3..T11-12 is then 4.0, the published
# men's mean. C7-T1 = T1-T2 (modelling choice). Lumbar: middle disc heights of the MRI study
# (REFERENCE 2b, V): L1/2 10.00, L2/3 11.59, L3/4 12.45, L4/5 13.82, L5/S1 12.99.
# T12-L1: mean of T11-12 and L1-2 (modelling choice).
DISC_HEIGHTS_MM = {
    "C7_T1": 3.0,
    "T1_T2": 3.0,
    "T2_T3": 3.0,
    "T3_T4": 2.85,
    "T4_T5": 2.7,
    "T5_T6": 3.15,
    "T6_T7": 3.6,
    "T7_T8": 4.05,
    "T8_T9": 4.5,
    "T9_T10": 4.95,
    "T10_T11": 5.4,
    "T11_T12": 5.85,
    "T12_L1": (5.85 + 10.00) / 2.0,
    "L1_L2": 10.00,
    "L2_L3": 11.59,
    "L3_L4": 12.45,
    "L4_L5": 13.82,
    "L5_S1": 12.99,
}

# --------------------------------------------------------------------------------------
# Spinal range of motion (REFERENCE.md section 1a): White & Panjabi 1990, representative
# values, status U. (flex+ext arc, lateral bending one side, axial rotation one side), deg.
# The row is the joint *below* the vertebra (L5 <- L5-S1, ..., T1 <- T1-T2).
# --------------------------------------------------------------------------------------

SPINE_ROM_1A = {
    "T1_T2": (4, 5, 9),
    "T2_T3": (4, 6, 8),
    "T3_T4": (4, 5, 8),
    "T4_T5": (4, 6, 8),
    "T5_T6": (4, 6, 8),
    "T6_T7": (5, 6, 8),
    "T7_T8": (6, 6, 8),
    "T8_T9": (6, 6, 7),
    "T9_T10": (6, 6, 4),
    "T10_T11": (9, 7, 2),
    "T11_T12": (12, 9, 2),
    "T12_L1": (12, 8, 2),
    "L1_L2": (12, 6, 2),
    "L2_L3": (14, 6, 2),
    "L3_L4": (15, 8, 2),
    "L4_L5": (16, 6, 2),
    "L5_S1": (17, 3, 1),
}
# C7-T1: representative values only, secondary transcription (REFERENCE 1a first row / 1b).
SPINE_ROM_C7_T1 = (9, 4, 2)

# --------------------------------------------------------------------------------------
# Limb joint ranges (REFERENCE.md section 3d), degrees. Signs: see data/README.md.
# --------------------------------------------------------------------------------------

SRC_SHOULDER = (
    "flexion 167 / extension 62: Boone & Azen 1979 (Norkin & White Table A.1); abduction 170: "
    "AMA >=170 (Table A.1); adduction 30: modelling choice; internal rotation 70 / external 90: "
    "AAOS (Table A.1); swing_max 175: modelling choice"
)
SRC_ELBOW = (
    "elbow flexion 150, extension 0: AAOS; forearm pronation 80 / supination 80: AAOS "
    "(Norkin & White Table A.1); twist 0 = neutral, palms to thighs"
)
SRC_WRIST = (
    "palmar flexion 80 / extension 70, radial deviation 20 / ulnar deviation 30: AAOS "
    "(Norkin & White Table A.1); pronation lives in the forearm; swing_max 85: modelling choice"
)
SRC_HIP = (
    "flexion 125, hyperextension 15, abduction 45, lateral/medial rotation 45: Merck Manual "
    "Table 1; adduction 25: VA 38 CFR 4.71 (as reproduced, S); swing_max 130: modelling choice"
)
SRC_KNEE = "knee flexion 130: Merck Manual Table 1; no tibial rotation figure in the references"
SRC_ANKLE = (
    "dorsiflexion 20 / plantar flexion 50, inversion 35 / eversion 25: Merck Manual Table 1 "
    "(talocrural hinge, inversion/eversion as twist)"
)
SRC_CLAVICLE = (
    "shoulder-girdle ranges are not in the references: modelling choice (cone 20, no twist)"
)
SRC_PELVIS = "rigid pelvis: its orientation is the whole body's (modelling choice)"
SRC_HEAD = (
    "whole cervical spine above C7 lumped into the skull_base joint; flexion 45 / extension 45 "
    "(modelling choice), lateral flexion 45 and axial rotation 70 (60-80): exrx.net, "
    "status S/U, not confirmed against AAOS or 38 CFR"
)

# --------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------

MM = 4  # decimals for metres (0.1 mm)
DEG = 2  # decimals for degrees
KG = 4  # decimals for kilograms
UNIT = 6  # decimals for unit direction vectors


def rnd(x: float, nd: int) -> float:
    v = round(float(x), nd)
    return 0.0 if v == 0 else v


def rvec(v, nd: int = MM) -> list[float]:
    return [rnd(c, nd) for c in v]


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def cross_of_axes(direction) -> np.ndarray:
    """Rotation whose columns are the segment's X, Y, Z axes in world (SCHEMA.md).

    Z = direction; X in the world XZ-plane, perpendicular to Z, with a positive forward
    component; X = world up if Z is +-world X, world forward if Z is +-world Y; Y = Z x X.
    """
    z = unit(direction)
    if abs(z[1]) < 1e-12 and abs(z[2]) < 1e-12:
        x = np.array([0.0, 0.0, 1.0])
    elif abs(z[0]) < 1e-12 and abs(z[2]) < 1e-12:
        x = np.array([1.0, 0.0, 0.0])
    else:
        x = np.array([z[2], 0.0, -z[0]])
        if x[0] < 0 or (x[0] == 0 and x[2] < 0):
            x = -x
        if abs(x[0]) < 1e-12:
            raise ValueError(f"direction {direction}: horizontal and oblique, X is ambiguous")
        x = unit(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def read_p50(sex: str) -> dict[str, float]:
    """ANSUR II medians of one sex, in metres (kg for weightkg)."""
    out: dict[str, float] = {}
    with open(PERCENTILES, encoding="utf-8", newline="") as f:
        rows = [r for r in csv.reader(f) if r and not r[0].startswith("#")]
    header = rows[0]
    i_sex, i_name, i_unit, i_p50 = (header.index(k) for k in ("sex", "measurement", "unit", "p50"))
    for r in rows[1:]:
        if r[i_sex] != sex:
            continue
        value = float(r[i_p50])
        out[r[i_name]] = value if r[i_unit] == "kg" else value / 1000.0
    return out


def interp(z: float, pts: list[tuple[float, float]]) -> float:
    zs, vs = zip(*pts)
    return float(np.interp(z, zs, vs))


def stations(z0: float, z1: float, radius, spacing: float) -> list[float]:
    """Positions from z0 to z1 (both included) with steps of about spacing * radius(z)."""
    zs = np.linspace(z0, z1, 2001)
    du = np.diff(zs) / (spacing * np.array([radius(z) for z in zs[:-1]]))
    u = np.concatenate([[0.0], np.cumsum(du)])
    n = max(1, math.ceil(u[-1] - 1e-9))
    return [float(np.interp(k * u[-1] / n, u, zs)) for k in range(n + 1)]


# --------------------------------------------------------------------------------------
# The body
# --------------------------------------------------------------------------------------


class Segment:
    def __init__(self, name: str, proximal: str, distal: str):
        self.name, self.proximal, self.distal = name, proximal, distal
        self.length = 0.0
        self.direction = [0.0, 0.0, 1.0]
        self.R = np.eye(3)
        self.p0 = np.zeros(3)  # world position of the proximal joint (after rounding)
        self.spheres: list[dict] = []
        self.standard_orientation = "swing"
        self.limits: dict = {}
        self.mass = 0.0
        self.centroid = [0.0, 0.0, 0.0]
        self.source = ""

    # spheres ---------------------------------------------------------------------------
    def local(self, p_world) -> np.ndarray:
        return self.R.T @ (np.asarray(p_world, dtype=float) - self.p0)

    def world(self, p_local) -> np.ndarray:
        return self.p0 + self.R @ np.asarray(p_local, dtype=float)

    def add(self, origin_local, radius, features=(), mirror_pair=False) -> None:
        """Add a sphere (origin in this segment's cross of axes). With mirror_pair, also add
        its mirror image y -> -y (for segments on the midline, whose Y is world left)."""
        o = rvec(origin_local)
        feats = [{"name": n, "direction": rvec(unit(d), UNIT)} for n, d in features]
        s = {"origin": o, "radius": rnd(radius, MM)}
        if feats:
            s["features"] = feats
        self.spheres.append(s)
        if mirror_pair and o[1] != 0.0:
            self.spheres.append({"origin": [o[0], rnd(-o[1], MM), o[2]], "radius": s["radius"]})

    def add_world(self, p_world, radius, features=(), mirror_pair=False) -> None:
        self.add(self.local(p_world), radius, features, mirror_pair)

    def volume(self) -> float:
        return sum(4.0 / 3.0 * math.pi * s["radius"] ** 3 for s in self.spheres)

    def volume_centroid(self) -> np.ndarray:
        w = np.array([s["radius"] ** 3 for s in self.spheres])
        o = np.array([s["origin"] for s in self.spheres])
        return (w[:, None] * o).sum(axis=0) / w.sum()


def box(sx, sy, tw, swing_max=None, source="") -> dict:
    d = {
        "kind": "box",
        "swing_x_deg": [rnd(v, DEG) for v in sx],
        "swing_y_deg": [rnd(v, DEG) for v in sy],
        "twist_deg": [rnd(v, DEG) for v in tw],
    }
    if swing_max is not None:
        d["swing_max_deg"] = rnd(swing_max, DEG)
    d["source"] = source
    return d


def hinge(sy, tw, source="") -> dict:
    return {
        "kind": "hinge",
        "swing_y_deg": [rnd(v, DEG) for v in sy],
        "twist_deg": [rnd(v, DEG) for v in tw],
        "source": source,
    }


def cone(swing_max, tw, source="") -> dict:
    return {
        "kind": "cone",
        "swing_max_deg": rnd(swing_max, DEG),
        "twist_deg": [rnd(v, DEG) for v in tw],
        "source": source,
    }


def neg(interval) -> list[float]:
    lo, hi = interval
    return [rnd(-hi, DEG), rnd(-lo, DEG)]


def build(variant: str, sex: str) -> dict:
    m = read_p50(sex)
    S = m["stature"]
    mass_total = m["weightkg"]

    # ---------------- skeleton targets (world, standard position) -----------------------
    z_hip = m["trochanterionheight"]
    z_knee = m["lateralfemoralepicondyleheight"]
    z_ankle = m["lateralmalleolusheight"]
    y_hip = m["hipbreadth"] / 4.0
    x_spine = -0.040
    z_L4L5 = m["iliocristaleheight"]
    z_C7T1 = m["cervicaleheight"]
    z_skull = S - m["tragiontopofhead"]
    L_ua = DELEVA["upper_arm_SJC_EJC"][sex][0] / 1000.0 * S / (DELEVA_STATURE_MM[sex] / 1000.0)
    y_sh = m["biacromialbreadth"] / 2.0 - 0.015
    z_sh = m["acromialheight"] - (m["acromionradialelength"] - L_ua)
    L_fa = m["radialestylionlength"]
    L_hand = m["handlength"]
    FL = m["footlength"]

    # vertebral column: proportions from body + half the discs above and below
    body_h = _vertebral_body_heights_mm()
    joints_below = {v: j for v, j in zip(VERTEBRAE, list(DISC_HEIGHTS_MM)[1:])}
    joints_above = {v: j for v, j in zip(VERTEBRAE, list(DISC_HEIGHTS_MM)[:-1])}
    w = {
        v: body_h[v] + 0.5 * (DISC_HEIGHTS_MM[joints_above[v]] + DISC_HEIGHTS_MM[joints_below[v]])
        for v in VERTEBRAE
    }
    scale = (z_C7T1 - z_L4L5) / sum(w[v] for v in VERTEBRAE[:-1])  # T1..L4 span L4-L5 to C7-T1
    vlen = {v: w[v] * scale for v in VERTEBRAE}  # metres
    z_L5S1 = z_L4L5 - vlen["L5"]

    target = {
        "center_hip": np.array([0.0, 0.0, z_hip]),
        "L5_S1": np.array([x_spine, 0.0, z_L5S1]),
        "left_hip": np.array([0.0, y_hip, z_hip]),
        "right_hip": np.array([0.0, -y_hip, z_hip]),
        "skull_base": np.array([0.0, 0.0, z_skull]),
        "vertex": np.array([0.0, 0.0, S]),
    }
    z = z_L5S1
    for v in reversed(VERTEBRAE):  # L5 up to T1
        z += vlen[v]
        target[joints_above[v]] = np.array([x_spine, 0.0, z])
    for side, sg in (("left", 1.0), ("right", -1.0)):
        target[f"{side}_shoulder"] = np.array([0.0, sg * y_sh, z_sh])
        target[f"{side}_elbow"] = np.array([0.0, sg * y_sh, z_sh - L_ua])
        target[f"{side}_wrist"] = np.array([0.0, sg * y_sh, z_sh - L_ua - L_fa])
        target[f"{side}_fingertip"] = np.array([0.0, sg * y_sh, z_sh - L_ua - L_fa - L_hand])
        target[f"{side}_knee"] = np.array([0.0, sg * y_hip, z_knee])
        target[f"{side}_ankle"] = np.array([0.0, sg * y_hip, z_ankle])
        target[f"{side}_toe_tip"] = np.array([0.78 * FL, sg * y_hip, z_ankle])

    # ---------------- segments in topological order ------------------------------------
    order: list[tuple[str, str, str]] = [
        ("pelvis", "center_hip", "L5_S1"),
        ("left_pelvis", "center_hip", "left_hip"),
        ("right_pelvis", "center_hip", "right_hip"),
    ]
    for v in reversed(VERTEBRAE):
        order.append((v, joints_below[v], joints_above[v]))
    order += [("neck", "C7_T1", "skull_base"), ("head", "skull_base", "vertex")]
    for side in ("left", "right"):
        order += [
            (f"{side}_clavicle", "C7_T1", f"{side}_shoulder"),
            (f"{side}_upper_arm", f"{side}_shoulder", f"{side}_elbow"),
            (f"{side}_forearm", f"{side}_elbow", f"{side}_wrist"),
            (f"{side}_hand", f"{side}_wrist", f"{side}_fingertip"),
        ]
    for side in ("left", "right"):
        order += [
            (f"{side}_thigh", f"{side}_hip", f"{side}_knee"),
            (f"{side}_shank", f"{side}_knee", f"{side}_ankle"),
            (f"{side}_foot", f"{side}_ankle", f"{side}_toe_tip"),
        ]

    seg: dict[str, Segment] = {}
    J: dict[str, np.ndarray] = {"center_hip": target["center_hip"].copy()}
    for name, prox, dist in order:
        s = Segment(name, prox, dist)
        d = target[dist] - J[prox]
        if name.startswith("right_"):
            # exact mirror of the left segment (already built)
            left = seg["left_" + name[6:]]
            s.length = left.length
            s.direction = [left.direction[0], rnd(-left.direction[1], UNIT), left.direction[2]]
        else:
            s.length = rnd(np.linalg.norm(d), MM)
            u = unit(d)
            # snap directions meant to be axis-aligned (limbs hang straight, feet point
            # forward, the spine is straight) so that rounding upstream leaves no 1e-6 tilt
            u = np.where(np.abs(u) < 1e-3, 0.0, u)
            s.direction = rvec(unit(u), UNIT)
        s.p0 = J[prox].copy()
        s.R = cross_of_axes(s.direction)
        J[dist] = J[prox] + s.length * unit(s.direction)
        seg[name] = s

    # ---------------- surface spheres ----------------------------------------------------
    twopi = 2.0 * math.pi
    SPACING = 0.6  # sphere spacing along a limb, as a fraction of the local radius

    # torso cross-sections (outer breadth, outer depth) per vertebra
    waist = (m["waistbreadth"], m["waistdepth"])
    chest = (m["chestbreadth"], m["chestdepth"])
    neck_base_d = m["neckcircumferencebase"] / math.pi
    top = (1.30 * neck_base_d, 1.05 * neck_base_d)  # T1: base of the neck with the trapezius
    hips = (m["hipbreadth"], m["buttockdepth"])
    lerp = lambda a, b, t: (a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t)  # noqa: E731
    # upper thorax: the breadth reaches the chest's quickly (shoulder girdle), the depth
    # slowly (the sternal notch, suprasternale, is ~80 mm below cervicale)
    up_b = {"T1": 0.0, "T2": 0.5, "T3": 0.8, "T4": 1.0, "T5": 1.0}
    up_d = {"T1": 0.0, "T2": 0.15, "T3": 0.35, "T4": 0.6, "T5": 0.85}
    section = {
        v: (top[0] + (chest[0] - top[0]) * up_b[v], top[1] + (chest[1] - top[1]) * up_d[v])
        for v in up_b
    }
    section.update(
        {
            "T6": chest,
            "T7": chest,
            "T8": chest,
            "L3": waist,
            "L4": waist,
            "L5": lerp(waist, hips, 0.25),
        }
    )
    mid = ["T9", "T10", "T11", "T12", "L1", "L2"]
    for i, v in enumerate(mid):
        section[v] = lerp(chest, waist, (i + 1) / (len(mid) + 1))
    BACK = 0.040  # back surface behind the spine (m)
    N_RING = 8

    def ring(s: Segment, z_local: float, breadth: float, depth: float) -> None:
        """A torso slice: N_RING spheres on an ellipse whose outer breadth and depth are
        the given ones, its back BACK behind the spine."""
        a, b = breadth / 2.0, depth / 2.0
        r = 0.6 * min(a, b)
        xc = b - BACK
        for k in range(N_RING // 2 + 1):  # angles 0..180 deg, mirrored for y < 0
            th = math.pi * k / (N_RING // 2)
            o = np.array([xc + (b - r) * math.cos(th), (a - r) * math.sin(th), z_local])
            s.add(o, r, mirror_pair=True)

    for v in VERTEBRAE:
        s = seg[v]
        breadth, depth = section[v]
        ring(s, s.length / 2.0, breadth, depth)

    # pelvis: two rings (hips/buttocks at trochanter level, and between it and L5-S1)
    pel = seg["pelvis"]
    lateral: list[tuple[np.ndarray, float]] = []
    z_top = J["L5_S1"][2]
    for frac, mix in ((0.05, 0.0), (0.55, 0.5)):
        zw = z_hip + frac * (z_top - z_hip)
        breadth, depth = lerp(hips, section["L5"], mix)
        xc_world = -0.020 * (1 - mix) + (x_spine + depth / 2 - BACK) * mix
        # express the ring in world then local (pelvis axis is tilted)
        a, b = breadth / 2.0, depth / 2.0
        r = 0.6 * min(a, b)
        for k in range(N_RING // 2 + 1):
            th = math.pi * k / (N_RING // 2)
            p = np.array([xc_world + (b - r) * math.cos(th), (a - r) * math.sin(th), zw])
            if k == N_RING // 4:
                lateral.append((p, r))
                continue
            pel.add_world(p, r, mirror_pair=True)
    # lower belly / pubic region in front, below the first ring
    pel.add_world([0.045, 0.0, z_hip - 0.035], 0.055 * S / 1.755)
    lp = seg["left_pelvis"]
    for p, r in lateral:
        lp.add_world(p, r)

    # neck
    nk = seg["neck"]
    r_nb = m["neckcircumferencebase"] / twopi
    r_nk = m["neckcircumference"] / twopi
    for t in (0.15, 0.42, 0.7, 0.95):
        r = r_nb + (r_nk - r_nb) * min(1.0, t / 0.7)
        nk.add([0.022, 0.0, t * nk.length], r)

    # head
    hd = seg["head"]
    r_c = m["headbreadth"] / 2.0
    x0 = 0.005
    HLn = m["headlength"]
    z_eye = S - (m["sittingheight"] - m["eyeheightsitting"])
    z_sellion = z_eye + 0.005
    z_menton = z_sellion - m["mentonsellionlength"]
    head_world: list[tuple[np.ndarray, float, list]] = []
    head_world.append((np.array([x0, 0.0, J["vertex"][2] - r_c]), r_c, [("top", (0, 0, 1))]))
    dxc = HLn / 2.0 - r_c
    head_world.append((np.array([x0 + dxc, 0.0, S - 1.25 * r_c]), r_c, []))
    head_world.append((np.array([x0 - dxc, 0.0, S - 1.25 * r_c]), r_c, []))
    head_world.append((np.array([x0 - 0.3 * dxc, 0.0, S - 1.75 * r_c]), 0.92 * r_c, []))
    r_face = 0.24 * HLn
    head_world.append((np.array([x0 + HLn / 2 - r_face - 0.004, 0.0, z_eye - 0.03]), r_face, []))
    r_chin = 0.11 * HLn
    chin = np.array([x0 + HLn / 2 - 0.01 - r_chin, 0.0, z_menton + r_chin])
    head_world.append((chin, r_chin, []))
    r_jaw = 0.19 * HLn
    jaw_y = m["bizygomaticbreadth"] / 2.0 - r_jaw
    jaw = np.array([x0 + 0.3 * dxc + 0.01, jaw_y, z_menton + 0.035 + r_jaw * 0.5])

    def surface_x(y: float, zz: float, items) -> float:
        best = -1.0
        for c, r, _ in items:
            h2 = r * r - (y - c[1]) ** 2 - (zz - c[2]) ** 2
            if h2 > 0:
                best = max(best, c[0] + math.sqrt(h2))
        return best

    for c, r, feats in head_world:
        hd.add_world(c, r, feats)
    hd.add_world(jaw, r_jaw, mirror_pair=True)
    r_nose = 0.06 * HLn
    z_nose = z_eye - 0.030
    x_nose = surface_x(0.0, z_nose, head_world) + 0.016 - r_nose
    hd.add_world([x_nose, 0.0, z_nose], r_nose, [("nose", (1, 0, 0))])
    r_eye = 0.06 * HLn
    y_eye = m["interpupillarybreadth"] / 2.0
    x_eye = surface_x(y_eye, z_eye, head_world) + 0.004 - r_eye
    hd.add_world([x_eye, y_eye, z_eye], r_eye, [("left_eye", (1, 0, 0))])
    hd.add_world([x_eye, -y_eye, z_eye], r_eye, [("right_eye", (1, 0, 0))])

    # ----- left limbs (right limbs are mirrored below) -----
    # clavicle: shoulder / trapezius line from the base of the neck to the deltoid
    cl = seg["left_clavicle"]
    r_tr = 0.55 * r_nb
    y_a, z_a = 0.8 * r_nb, J["C7_T1"][2] + 0.02  # side of the neck base (top surface)
    y_b, z_b = m["biacromialbreadth"] / 2.0 - 0.025, m["acromialheight"]  # acromion (top)
    for t in (0.0, 0.33, 0.66, 1.0):
        yy = y_a + (y_b - y_a) * t
        zt = z_a + (z_b - z_a) * t
        cl.add_world([-0.015, yy, zt - r_tr], r_tr * (1.0 - 0.2 * t))

    # upper arm: deltoid (from bideltoid breadth) -> biceps (flexed) -> elbow
    ua = seg["left_upper_arm"]
    r_delt = m["bideltoidbreadth"] / 2.0 - y_sh
    r_bic = m["bicepscircumferenceflexed"] / twopi
    r_fa = m["forearmcircumferenceflexed"] / twopi
    r_elb = 0.85 * r_fa
    Lu = ua.length
    prof_ua = [(0.05 * Lu, r_delt), (0.45 * Lu, r_bic), (Lu, r_elb)]
    for k, zz in enumerate(stations(0.05 * Lu, Lu, lambda q: interp(q, prof_ua), SPACING)):
        feats = [("shoulder", (0, -1, 0))] if k == 0 else []
        ua.add([0.0, 0.0, zz], interp(zz, prof_ua), feats)

    # forearm: elbow -> flexed forearm circumference -> wrist
    fa = seg["left_forearm"]
    Lf = fa.length
    r_wr = m["wristcircumference"] / twopi
    prof_fa = [(0.0, r_elb), (0.25 * Lf, r_fa), (Lf, r_wr)]
    for k, zz in enumerate(stations(0.0, Lf, lambda q: interp(q, prof_fa), SPACING)):
        feats = [("elbow", (-1, 0, 0))] if k == 0 else []
        fa.add([0.0, 0.0, zz], interp(zz, prof_fa), feats)

    # hand: palm block (3 columns across the hand breadth, flat in Y) + fingers + thumb.
    # Left hand: palm normal +Y local (world right, toward the thigh), thumb forward (+X).
    hn = seg["left_hand"]
    Lh = hn.length
    HB = m["handbreadth"]
    PL = m["palmlength"]
    r_p = 0.19 * HB  # half the hand thickness (modelling choice: thickness 0.38 x breadth)
    xcol = HB / 2.0 - r_p
    palm_z = np.linspace(0.35 * r_p, PL - 0.2 * r_p, 7)
    for i, zz in enumerate(palm_z):
        width = 0.7 + 0.3 * min(1.0, i / 2)  # narrower at the wrist
        for cx in (-xcol * width, 0.0, xcol * width):
            feats = [("palm", (0, 1, 0))] if (cx == 0.0 and i == 3) else []
            hn.add([cx, 0.0, zz], r_p, feats)
    # fingers (a mitten: little+ring / middle / index columns; the middle one reaches the
    # fingertip joint, the others stop short of it)
    r_f0, r_f1 = 0.80 * r_p, 0.60 * r_p

    def r_f(q: float) -> float:
        return r_f0 + (r_f1 - r_f0) * (q - PL) / (Lh - PL)

    for cx, frac in ((-xcol * 0.92, 0.80), (0.0, 1.0), (xcol * 0.92, 0.90)):
        z_end = PL + frac * (Lh - PL) - r_f1
        zs = stations(PL + 0.6 * r_p, z_end, r_f, 1.15)
        for j, zz in enumerate(zs):
            if cx == 0.0 and j == len(zs) - 1:
                hn.add([0.0, 0.0, Lh - r_f1], r_f1, [("fingertip", (0, 0, 1))])
            else:
                hn.add([cx, 0.0, zz], r_f(zz))
    # thumb: from the base of the palm, forward and down, slightly to the palm side
    r_t = 0.72 * r_p
    for t in (0.0, 0.5, 1.0):
        hn.add(
            [xcol + 0.2 * r_p + t * 0.45 * r_p, 0.35 * r_p * t, 0.3 * PL + t * 0.42 * PL],
            r_t * (1.0 - 0.15 * t),
        )

    # thigh: thigh circumference -> lower thigh circumference, capped at hipbreadth/4 so the
    # two thighs touch but do not overlap and the hips are hipbreadth wide
    th_ = seg["left_thigh"]
    Lt = th_.length
    r_cap = m["hipbreadth"] / 4.0
    r_th = m["thighcircumference"] / twopi
    r_lth = m["lowerthighcircumference"] / twopi
    prof_th = lambda q: min(r_cap, r_th + (r_lth - r_th) * q / Lt)  # noqa: E731
    zs = stations(0.0, Lt, prof_th, SPACING)
    for k, zz in enumerate(zs):
        feats = []
        if k == 0:
            feats = [("hip", (0, -1, 0))]
        if k == len(zs) - 1:
            feats = [("knee", (1, 0, 0))]
        th_.add([0.0, 0.0, zz], prof_th(zz), feats)

    # shank: knee -> calf (upper third) -> ankle
    sh = seg["left_shank"]
    Ls = sh.length
    r_calf = m["calfcircumference"] / twopi
    r_ank = m["anklecircumference"] / twopi
    prof_sh = [(0.0, 0.92 * r_calf), (Ls / 3.0, r_calf), (Ls, r_ank)]
    for zz in stations(0.0, Ls, lambda q: interp(q, prof_sh), SPACING):
        sh.add([0.0, 0.0, zz], interp(zz, prof_sh))

    # foot (world design, left foot). Sole at z = 0, heel 0.22 FL behind the ankle, toe tip
    # 0.78 FL in front; breadth footbreadthhorizontal at the ball, heelbreadth at the heel.
    ft = seg["left_foot"]
    ax, ay, az = J["left_ankle"]
    x_heel = ax - 0.22 * FL
    x_toe = ax + 0.78 * FL
    x_ball = x_heel + m["balloffootlength"]
    FB = m["footbreadthhorizontal"]
    r_heel = m["heelbreadth"] / 2.0
    # central column: heel -> under the ankle (instep) -> ball -> toe tip, every sphere on
    # the sole (centre height = radius)
    r_instep = 0.62 * az
    r_ball_c = 0.30 * FB
    r_tip = 0.13 * FB
    prof_ft = [
        (x_heel + r_heel, r_heel),
        (ax + 0.2 * (x_ball - ax), r_instep),
        (x_ball, r_ball_c),
        (x_toe - r_tip, r_tip),
    ]
    xs = stations(x_heel + r_heel, x_toe - r_tip, lambda q: interp(q, prof_ft), 0.7)
    i_ball = int(np.argmin([abs(x - x_ball) for x in xs]))
    for k, xx in enumerate(xs):
        rr = interp(xx, prof_ft)
        feats = []
        if k == 0:
            feats = [("heel", (0, 0, -1))]
        elif k == len(xs) - 1:
            feats = [("toe", (0, 0, 1))]
        elif k == i_ball:
            feats = [("sole", (-1, 0, 0))]
        ft.add_world([xx, ay, rr], rr, feats)
    # side columns (medial and lateral) from the midfoot to the toes: foot breadth
    r_side = 0.25 * FB
    y_side = FB / 2.0 - r_side
    x_s0 = ax + 0.3 * (x_ball - ax)
    x_s1 = x_ball + 0.45 * (x_toe - x_ball)
    prof_side = [(x_s0, 0.9 * r_side), (x_ball, r_side), (x_s1, 0.65 * r_side)]
    for xx in stations(x_s0, x_s1, lambda q: interp(q, prof_side), 1.3):
        rr = interp(xx, prof_side)
        wy = y_side * (0.8 + 0.2 * min(1.0, (xx - x_s0) / (x_ball - x_s0)))
        ft.add_world([xx, ay + wy, rr], rr)
        ft.add_world([xx, ay - wy, rr], rr)

    # ----- mirror the left limbs onto the right -----
    for lname in (
        "left_pelvis",
        "left_clavicle",
        "left_upper_arm",
        "left_forearm",
        "left_hand",
        "left_thigh",
        "left_shank",
        "left_foot",
    ):
        L = seg[lname]
        Rs = seg["right_" + lname[5:]]
        for sp in L.spheres:
            o = sp["origin"]
            new = {"origin": [o[0], rnd(-o[1], MM), o[2]], "radius": sp["radius"]}
            if "features" in sp:
                new["features"] = [
                    {
                        "name": f["name"],
                        "direction": [
                            f["direction"][0],
                            rnd(-f["direction"][1], UNIT),
                            f["direction"][2],
                        ],
                    }
                    for f in sp["features"]
                ]
            Rs.spheres.append(new)

    # ---------------- masses and centroids ----------------------------------------------
    frac = {k: DELEVA[k][sex][1] / 100.0 for k in DELEVA}
    total_frac = (
        frac["head_VERT_CERV"]
        + frac["upper_trunk_CERV_XYPH"]
        + frac["middle_trunk_XYPH_OMPH"]
        + frac["lower_trunk_OMPH_MIDH"]
        + 2
        * sum(
            frac[k]
            for k in (
                "upper_arm_SJC_EJC",
                "forearm_EJC_WJC",
                "hand_WJC_DAC3",
                "thigh_HJC_KJC",
                "shank_KJC_LMAL",
                "foot_HEEL_TTIP",
            )
        )
    )
    M = {k: mass_total * f / total_frac for k, f in frac.items()}  # normalised to sum 100 %
    mass: dict[str, float] = {}
    centroid: dict[str, np.ndarray] = {}
    src: dict[str, str] = {}
    norm_note = (
        ""
        if abs(total_frac - 1) < 1e-12
        else (f" (de Leva fractions sum to {100 * total_frac:.2f} %, normalised to 100 %)")
    )

    def split(row: str, names: list[str]) -> None:
        vols = {n: seg[n].volume() for n in names}
        vt = sum(vols.values())
        for n in names:
            mass[n] = M[row] * vols[n] / vt
            centroid[n] = seg[n].volume_centroid()
            src[n] = (
                f"mass: {DELEVA_LABEL[row]} ({DELEVA[row][sex][1]} % of body mass, "
                f"{sex}) split over {', '.join(names)} by sphere volume{norm_note}; "
                "centroid: sphere-volume centroid"
            )

    split("upper_trunk_CERV_XYPH", VERTEBRAE[:9] + ["left_clavicle", "right_clavicle"])
    split("middle_trunk_XYPH_OMPH", VERTEBRAE[9:15])
    split("lower_trunk_OMPH_MIDH", ["L4", "L5", "pelvis", "left_pelvis", "right_pelvis"])

    # head + neck: VERT-CERV row split by sphere volume; the head's centroid is de Leva's CM
    # (cm % of the vertex -> C7-T1 distance from the vertex, on that line), the neck's
    # centroid is its sphere-volume centroid.
    row = "head_VERT_CERV"
    vh, vn = seg["head"].volume(), seg["neck"].volume()
    mass["head"] = M[row] * vh / (vh + vn)
    mass["neck"] = M[row] * vn / (vh + vn)
    centroid["neck"] = seg["neck"].volume_centroid()
    cm = DELEVA[row][sex][2] / 100.0
    centroid["head"] = seg["head"].local(J["vertex"] + cm * (J["C7_T1"] - J["vertex"]))
    src["head"] = (
        f"mass: {DELEVA_LABEL[row]} ({DELEVA[row][sex][1]} %, {sex}) split with "
        f"the neck by sphere volume{norm_note}; centroid: de Leva CM "
        f"({DELEVA[row][sex][2]} % from the vertex on the vertex-C7_T1 line)"
    )
    src["neck"] = (
        f"mass: {DELEVA_LABEL[row]} ({DELEVA[row][sex][1]} %, {sex}) split with "
        f"the head by sphere volume{norm_note}; centroid: sphere-volume centroid"
    )

    limb_rows = {
        "upper_arm": "upper_arm_SJC_EJC",
        "forearm": "forearm_EJC_WJC",
        "hand": "hand_WJC_DAC3",
        "thigh": "thigh_HJC_KJC",
        "shank": "shank_KJC_LMAL",
    }
    for side in ("left", "right"):
        for part, row in limb_rows.items():
            n = f"{side}_{part}"
            mass[n] = M[row]
            centroid[n] = np.array([0.0, 0.0, DELEVA[row][sex][2] / 100.0 * seg[n].length])
            src[n] = (
                f"mass and centroid: {DELEVA_LABEL[row]} ({DELEVA[row][sex][1]} %, CM "
                f"{DELEVA[row][sex][2]} % from the proximal joint, {sex}){norm_note}"
            )
        n = f"{side}_foot"
        row = "foot_HEEL_TTIP"
        mass[n] = M[row]
        vc = seg[n].volume_centroid()
        zc = -0.22 * FL + DELEVA[row][sex][2] / 100.0 * FL
        centroid[n] = np.array([vc[0], 0.0, zc])
        src[n] = (
            f"mass and centroid: {DELEVA_LABEL[row]} ({DELEVA[row][sex][1]} %, CM "
            f"{DELEVA[row][sex][2]} % of heel-toe length from the heel, {sex}){norm_note}; "
            "heel at -0.22 footlength; centroid height: sphere-volume centroid"
        )

    # round, and put the rounding residue on the heaviest midline segment so the sum is
    # exact and left and right stay equal
    rounded = {n: rnd(v, KG) for n, v in mass.items()}
    residue = rnd(rnd(mass_total, KG) - sum(rounded.values()), KG)
    midline = [n for n in rounded if not n.startswith(("left_", "right_"))]
    heaviest = max(midline, key=lambda n: rounded[n])
    rounded[heaviest] = rnd(rounded[heaviest] + residue, KG)
    for n, s in seg.items():
        s.mass = rounded[n]
        c = centroid[n]
        if n.startswith("right_"):  # exact mirror of the left centroid
            c = centroid["left_" + n[6:]] * np.array([1.0, -1.0, 1.0])
        s.centroid = rvec(c)
        s.source = src[n]

    # ---------------- joint limits ------------------------------------------------------
    for v in VERTEBRAE:
        jb = joints_below[v]
        fe, lb, ar = SPINE_ROM_1A[jb]
        share = 0.6 if v.startswith("L") else 0.5
        fl = share * fe
        seg[v].limits = box(
            [-lb, lb],
            [-(fe - fl), fl],
            [-ar, ar],
            source=(
                f"{jb.replace('_', '-')} row, representative values (F+E {fe}, LB {lb}, AR {ar}): "
                f"{CITE_WP}, REFERENCE 1a status U; flexion {share:.0%} of F+E "
                "(build_spine.py's approximation)"
            ),
        )
    fe, lb, ar = SPINE_ROM_C7_T1
    seg["neck"].limits = box(
        [-lb, lb],
        [-fe / 2, fe / 2],
        [-ar, ar],
        source=(
            f"C7-T1 row, representative values (F+E {fe} split 50/50, LB {lb}, AR {ar}): "
            f"{CITE_WP_1B}, REFERENCE 1b status S"
        ),
    )
    seg["head"].limits = box([-45, 45], [-45, 45], [-70, 70], source=SRC_HEAD)
    for n in ("pelvis", "left_pelvis", "right_pelvis"):
        seg[n].limits = box([0, 0], [0, 0], [0, 0], source=SRC_PELVIS)
    sides = {"left": 1, "right": -1}
    for side, sg in sides.items():
        mir = (lambda iv: [rnd(iv[0], DEG), rnd(iv[1], DEG)]) if sg > 0 else neg
        seg[f"{side}_clavicle"].limits = cone(20, [0, 0], source=SRC_CLAVICLE)
        seg[f"{side}_upper_arm"].limits = box(
            mir([-30, 170]), [-62, 167], mir([-90, 70]), swing_max=175, source=SRC_SHOULDER
        )
        seg[f"{side}_forearm"].limits = hinge([0, 150], [-80, 80], source=SRC_ELBOW)
        seg[f"{side}_hand"].limits = box(
            mir([-80, 70]), [-30, 20], [0, 0], swing_max=85, source=SRC_WRIST
        )
        seg[f"{side}_thigh"].limits = box(
            mir([-25, 45]), [-15, 125], [-45, 45], swing_max=130, source=SRC_HIP
        )
        seg[f"{side}_shank"].limits = hinge([-130, 0], [0, 0], source=SRC_KNEE)
        seg[f"{side}_foot"].limits = hinge([-50, 20], mir([-35, 25]), source=SRC_ANKLE)
        seg[f"{side}_upper_arm"].standard_orientation = f"{side}_arm"
        seg[f"{side}_thigh"].standard_orientation = f"{side}_leg"

    # ---------------- document ----------------------------------------------------------
    description = (
        f"Default {sex} body, ANSUR II P50 ({sex}): stature {S * 1000:.0f} mm, mass "
        f"{mass_total:.1f} kg. Standard position (Badler & O'Rourke 1979): upright, feet flat, "
        "toes forward, arms at the sides, palms toward the thighs, facing +X; straight spine. "
        "17 vertebrae T1-L5 with torso slices; built by data/build_bodies.py (see data/README.md)."
    )
    segments = []
    for name, _, _ in order:
        s = seg[name]
        segments.append(
            {
                "name": s.name,
                "proximal": s.proximal,
                "distal": s.distal,
                "length": s.length,
                "direction": s.direction,
                "standard_orientation": s.standard_orientation,
                "limits": s.limits,
                "mass": s.mass,
                "centroid": s.centroid,
                "source": s.source,
                "spheres": s.spheres,
            }
        )
    return {
        "schema": SCHEMA,
        "name": variant,
        "description": description,
        "sources": SOURCES,
        "root_joint": "center_hip",
        # The spine database that drives the vertebrae (data/spine.json, data/build_spine.py).
        "spine": "spine.json",
        "segments": segments,
    }


# --------------------------------------------------------------------------------------
# Output: pretty JSON with short arrays and spheres on one line
# --------------------------------------------------------------------------------------


def dumps(obj, indent: int = 0, width: int = 100) -> str:
    compact = json.dumps(obj, ensure_ascii=False, separators=(", ", ": "))
    if (
        not isinstance(obj, (dict, list))
        or len(compact) + indent <= width
        or (isinstance(obj, list) and all(isinstance(v, (int, float)) for v in obj))
    ):
        return compact
    pad = " " * (indent + 2)
    if isinstance(obj, dict):
        items = [f"{pad}{json.dumps(k)}: {dumps(v, indent + 2, width)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + "\n" + " " * indent + "}"
    items = [pad + dumps(v, indent + 2, width) for v in obj]
    return "[\n" + ",\n".join(items) + "\n" + " " * indent + "]"


def main() -> None:
    for variant, sex in (("male50", "male"), ("female50", "female")):
        body = build(variant, sex)
        path = DATA / f"body_{variant}.json"
        path.write_text(dumps(body) + "\n", encoding="utf-8")
        n = sum(len(s["spheres"]) for s in body["segments"])
        print(f"wrote {path} ({len(body['segments'])} segments, {n} spheres)")


if __name__ == "__main__":
    main()
