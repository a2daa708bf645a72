"""Build the spine database data/spine.json (Monheit & Badler 1991, "Spine database").

Usage::

    python data/build_spine.py

Reads only files in ``data/``: it imports the spine tables of ``data/build_bodies.py`` (range
of motion, disc heights, vertebral body heights, citations) so that the database and the
default bodies use the same numbers, and it checks its limits against ``data/body_*.json``.
Every other number is a constant below with its citation and its status from
../shared/reference/REFERENCE.md (V: read in a primary source or a faithful reproduction;
S: secondary transcription; U: not confirmed). The choices are listed in data/README.md,
section "Spine database (data/spine.json)". The script is deterministic.

17 moving vertebrae T1..L5 and 18 joints C7_T1..L5_S1; the joint below a vertebra moves it
(T1_T2 moves T1, ..., L5_S1 moves L5; C7_T1 moves the neck). Angles are (flexion, axial,
lateral) in degrees: flexion about the body's Y (left) axis, positive forward; axial rotation
about Z (up), positive to the left; lateral bending about X (forward), positive to the right.
"""

from __future__ import annotations

import importlib.util
import json
import math
import pathlib

import numpy as np

DATA = pathlib.Path(__file__).resolve().parent
OUT = DATA / "spine.json"
SCHEMA = "diffbody.spine/1"
ANGLES = (
    "degrees; (flexion, axial, lateral): flexion right-handed about the body's Y (left) axis, "
    "positive = bending forward; axial rotation about Z (up), positive = turning to the left; "
    "lateral bending about X (forward), positive = bending to the right"
)


def _load_build_bodies():
    """data/build_bodies.py as a module (data/ is not a package)."""
    spec = importlib.util.spec_from_file_location("build_bodies", DATA / "build_bodies.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


BB = _load_build_bodies()

VERTEBRAE = BB.VERTEBRAE  # T1..T12, L1..L5 (17)
JOINTS = list(BB.DISC_HEIGHTS_MM)  # C7_T1, T1_T2, ..., L5_S1 (18), from the top
SEGMENT = {j: ("neck" if j == "C7_T1" else j.split("_")[0]) for j in JOINTS}
LOWER = {j: j.split("_")[1] for j in JOINTS}  # the vertebra below the disc (C7_T1 -> T1)

DEG = 2  # decimals for degrees
MM = 3  # decimals for millimetres (keeps 7.925, the T12-L1 disc, exact)


def rnd(x: float, nd: int) -> float:
    v = round(float(x), nd)
    return 0.0 if v == 0 else v


# --------------------------------------------------------------------------------------
# Citations (REFERENCE.md sections 1d, 2a, 2c; the others are build_bodies.py's)
# --------------------------------------------------------------------------------------

CITE_AO = (
    "AO Foundation Surgery Reference, Sagittal spinal alignment (spine / tumors / further "
    "reading): thoracic kyphosis T1-T12 40, thoracolumbar junction T11-L1 0, lumbar lordosis "
    "60, L4-L5 20 and L5-S1 28 (REFERENCE 1d, status V, web page)"
)
CITE_SPINE_SECRETS = (
    "Spine Secrets, 'What are normal values for the sagittal curves...', citing DeWald RL, "
    "1992, Revision surgery for spinal deformity, Instr Course Lect 41: kyphosis starts at "
    "T1-T2, apex at the T6-T7 disc, decreasing to the TL junction; T12-L1 essentially "
    "straight; lordosis L1-S1 mean 60, begins at L1-L2, increases at each level caudally, "
    "apex at the L3-L4 disc (REFERENCE 1d, status V, secondary textbook)"
)
CITE_THORACIC_POOLED = (
    "A Morphometric Study of the Vertebral Body in Dry Human Typical Thoracic Vertebrae, "
    "Int J Anat Physiol Biochem (eternalpublication.com), 2015 (authors not captured): "
    "pooled typical thoracic AP depth 20.78, transverse diameter 27.02 mm, sex not stated "
    "(REFERENCE 2a, status V, abstract)"
)
CITE_PEARCY_BOGDUK = (
    "Pearcy MJ, Bogduk N, 1988, Instantaneous axes of rotation of the lumbar intervertebral "
    "joints, Spine 13(9):1033-1041: coordinates not retrieved; 'posterior half of the lower "
    "vertebral body, near its superior endplate' is the commonly cited location (REFERENCE 2c, "
    "status V abstract / U location)"
)

SOURCES = [
    BB.CITE_MONHEIT,
    CITE_AO,
    CITE_SPINE_SECRETS,
    BB.CITE_WP,
    BB.CITE_WP_1B,
    BB.CITE_EGWU,
    CITE_THORACIC_POOLED,
    BB.CITE_L5,
    BB.CITE_FLETCHER,
    BB.CITE_MRI_DISC,
    CITE_PEARCY_BOGDUK,
]

# --------------------------------------------------------------------------------------
# Rest posture (REFERENCE 1d). Flexion only; axial and lateral rest angles are 0.
# --------------------------------------------------------------------------------------

KYPHOSIS_DEG = 40.0  # T1-T12 (joints T1_T2..T11_T12): AO Foundation, V
LORDOSIS_DEG = 60.0  # L1-S1 (joints L1_L2..L5_S1), as extension: AO (T12-S1) / Spine Secrets
#                      (L1-S1 mean 60), V
L4_L5_DEG = 20.0  # AO Foundation, V (lordosis, i.e. extension)
L5_S1_DEG = 28.0  # AO Foundation, V (lordosis, i.e. extension)
TL_JUNCTION_DEG = 0.0  # T11-L1 (joints T11_T12, T12_L1): AO 0 / Spine Secrets "straight", V
C7_T1_REST_DEG = 0.0  # modelling choice (the cervical lordosis is not in this database)
KYPHOSIS_APEX = "T6_T7"  # Spine Secrets / DeWald 1992, V (secondary)
THORACIC = JOINTS[1:12]  # T1_T2 .. T11_T12
LUMBAR = JOINTS[13:]  # L1_L2 .. L5_S1


def _round_to_total(values: dict[str, float], total: float, sink: str) -> dict[str, float]:
    """Round to DEG decimals; the rounding residue goes to `sink` so the sum is exact."""
    out = {k: rnd(v, DEG) for k, v in values.items()}
    out[sink] = rnd(out[sink] + total - sum(out.values()), DEG)
    return out


def rest_flexion() -> tuple[dict[str, float], float]:
    """Per-joint rest flexion (deg) and the lumbar growth ratio.

    Thoracic kyphosis: a half sine over the joint index k (C7_T1 = 0, T1_T2 = 1, ...,
    T11_T12 = 11) with nodes at C7_T1 and T11_T12 and its crest at T6_T7 (k = 6), the index
    stretched piecewise linearly (6 joints up to the crest, 5 down from it):
    w_k = sin(pi g_k), g_k = k / 12 (k <= 6), 1/2 + (k - 6) / 10 (k >= 6); scaled to 40.
    T11_T12 = T12_L1 = 0 keeps T11-L1 straight. Lumbar lordosis: L1_L2..L4_L5 a geometric
    progression (constant ratio r) ending at L4_L5 = -20 with L1_L2 + L2_L3 + L3_L4 =
    -(60 - 20 - 28) = -12, i.e. r^3 = (20/12)(1 + r + r^2); L5_S1 = -28.
    """
    rest = {j: 0.0 for j in JOINTS}
    rest["C7_T1"] = C7_T1_REST_DEG
    a = THORACIC.index(KYPHOSIS_APEX) + 1  # 6
    n = len(THORACIC)  # 11
    w = {}
    for k, j in enumerate(THORACIC, start=1):
        g = 0.5 * k / a if k <= a else 0.5 + 0.5 * (k - a) / (n - a)
        w[j] = math.sin(math.pi * g)
    w[THORACIC[-1]] = 0.0  # sin(pi) exactly
    s = sum(w.values())
    rest.update(
        _round_to_total(
            {j: KYPHOSIS_DEG * v / s for j, v in w.items()}, KYPHOSIS_DEG, KYPHOSIS_APEX
        )
    )
    rest["T11_T12"] = TL_JUNCTION_DEG
    rest["T12_L1"] = TL_JUNCTION_DEG

    upper = LORDOSIS_DEG - L4_L5_DEG - L5_S1_DEG  # 12
    c = L4_L5_DEG / upper
    roots = np.roots([1.0, -c, -c, -c])
    r = float(max(z.real for z in roots if abs(z.imag) < 1e-12))
    x1 = L4_L5_DEG / r**3
    raw = {"L1_L2": -x1, "L2_L3": -x1 * r, "L3_L4": -x1 * r * r}
    rest.update(_round_to_total(raw, -upper, "L3_L4"))
    rest["L4_L5"] = -L4_L5_DEG
    rest["L5_S1"] = -L5_S1_DEG
    return rest, r


# --------------------------------------------------------------------------------------
# Range of motion (REFERENCE 1a/1b): build_bodies.SPINE_ROM_1A (White & Panjabi 1990,
# representative values, status U) and build_bodies.SPINE_ROM_C7_T1 (9/4/2, status S).
# Rows are (flex+ext arc, lateral bending one side, axial rotation one side).
# Flexion share of F+E: 0.6 at lumbar joints L1_L2..L5_S1, 0.5 elsewhere (T12_L1 counts as
# thoracolumbar): build_spine.py's "usual approximation" (REFERENCE 1b), not a W&P value.
# --------------------------------------------------------------------------------------

ROM = {"C7_T1": BB.SPINE_ROM_C7_T1, **BB.SPINE_ROM_1A}

# REFERENCE 1b (secondary transcription) cells that differ from 1a; 1a is kept, as in
# build_bodies.py. (joint, quantity, 1a, 1b)
ROM_1A_1B_DISAGREEMENTS = [
    ("T1_T2", "LB", 5, 6),
    ("T2_T3", "AR", 8, 9),
    ("T3_T4", "LB", 5, 6),
    ("T3_T4", "AR", 8, 9),
    ("T4_T5", "AR", 8, 9),
    ("T8_T9", "AR", 7, 6),
    ("L4_L5", "F+E", 16, 17),
    ("L5_S1", "F+E", 17, 20),
    ("L5_S1", "AR", 1, 5),
]


def flexion_share(joint: str) -> float:
    return 0.6 if joint.startswith("L") else 0.5


def rom(joint: str) -> tuple[float, float, float, float]:
    """(flexion, extension, lateral one side, axial one side) in degrees, around rest."""
    fe, lb, ar = ROM[joint]
    fl = flexion_share(joint) * fe
    return fl, fe - fl, lb, ar


# --------------------------------------------------------------------------------------
# Vertebra sizes (REFERENCE 2a), mm: [depth_x, breadth_y, height_z]
# --------------------------------------------------------------------------------------

# height_z: build_bodies._vertebral_body_heights_mm() (mean of anterior and posterior body
# height): T2 and T9 Egwu et al. 2019 (V, adult males), linear T1..T12; L5 (30.3+26.3)/2
# Int J Spine Surg Table 6 total sample (V); L1 = 25.0 modelling choice; L1..L5 linear.
BODY_HEIGHT_MM = BB._vertebral_body_heights_mm()

THORACIC_DEPTH_MM = 20.78  # pooled typical thoracic AP depth (V, abstract; sex not stated)
THORACIC_BREADTH_MM = 27.02  # pooled typical thoracic transverse diameter (V, abstract)
TYPICAL_THORACIC = [f"T{i}" for i in range(2, 10)]  # T2..T9 take the pooled row
L5_DEPTH_MM = (37.1 + 36.7) / 2.0  # male superior / inferior depth, Int J Spine Surg Table 6, V
# L5 breadth: no figure in the references. Modelling choice (U): the pooled thoracic
# breadth / depth ratio (27.02 / 20.78) times the L5 depth.
L5_BREADTH_MM = L5_DEPTH_MM * THORACIC_BREADTH_MM / THORACIC_DEPTH_MM


def vertebra_sizes() -> dict[str, tuple[list[float], str]]:
    """[depth, breadth, height] (mm) and a source string per vertebra."""
    i9, i5 = VERTEBRAE.index("T9"), VERTEBRAE.index("L5")
    h_src = {
        **{v: "height: Egwu et al. 2019 T2/T9 (V), linear (interpolated)" for v in VERTEBRAE},
        "T1": "height: Egwu et al. 2019 T2/T9 (V), extrapolated linearly to T1",
        "T2": "height: (16.93 + 17.59)/2, Egwu et al. 2019 T2 (V, adult males)",
        "T9": "height: (18.83 + 20.46)/2, Egwu et al. 2019 T9 (V, adult males)",
        "L1": "height: 25.0 mm modelling choice (no lumbar per-level figure in the references)",
        "L5": "height: (30.3 + 26.3)/2, Int J Spine Surg Table 6 total sample (V), as "
        "build_bodies.py (male: (30.7 + 26.8)/2 = 28.75)",
    }
    for v in ("T10", "T11", "T12"):
        h_src[v] = "height: Egwu et al. 2019 T2/T9 (V), extrapolated linearly (T2-T9 slope)"
    for v in ("L2", "L3", "L4"):
        h_src[v] = "height: interpolated linearly between L1 (modelling choice) and L5 (V)"
    out = {}
    for i, v in enumerate(VERTEBRAE):
        if v in TYPICAL_THORACIC:
            d, b = THORACIC_DEPTH_MM, THORACIC_BREADTH_MM
            db_src = "depth, breadth: pooled typical thoracic row (V, sex not stated)"
        elif v == "T1":
            d, b = THORACIC_DEPTH_MM, THORACIC_BREADTH_MM
            db_src = (
                "depth, breadth: pooled typical thoracic row copied to the atypical T1 "
                "(modelling choice, U)"
            )
        elif v == "L5":
            d, b = L5_DEPTH_MM, L5_BREADTH_MM
            db_src = (
                "depth: mean of male superior 37.1 / inferior 36.7 depth, Int J Spine Surg "
                "Table 6 (V); breadth: no figure, depth x thoracic breadth/depth ratio "
                "27.02/20.78 (modelling choice, U)"
            )
        else:  # T10..L4: linear in level between T9 (pooled) and L5
            t = (i - i9) / (i5 - i9)
            d = THORACIC_DEPTH_MM + t * (L5_DEPTH_MM - THORACIC_DEPTH_MM)
            b = THORACIC_BREADTH_MM + t * (L5_BREADTH_MM - THORACIC_BREADTH_MM)
            db_src = (
                "depth, breadth: interpolated linearly in level between T9 (pooled typical "
                "thoracic row, V) and L5 (Int J Spine Surg Table 6 male depth, V; breadth U)"
            )
        out[v] = ([rnd(d, MM), rnd(b, MM), rnd(BODY_HEIGHT_MM[v], MM)], f"{db_src}; {h_src[v]}")
    return out


# --------------------------------------------------------------------------------------
# Disc heights (REFERENCE 2b), mm: build_bodies.DISC_HEIGHTS_MM
# --------------------------------------------------------------------------------------

DISC_SRC = {
    "C7_T1": "C7-T1 = T1-T2 (modelling choice)",
    "T1_T2": "3.0 (modelling choice: Fletcher et al. 2015 'T4-5 similar to or smaller than "
    "T2-3'; mean T2-3..T11-12 then 4.0, their men's mean, V)",
    "T2_T3": "3.0 (modelling choice, as T1-T2)",
    "T3_T4": "between T2-T3 and T4-T5 (interpolated)",
    "T4_T5": "anterior, men, Fletcher et al. 2015 (V)",
    "T10_T11": "anterior, men, Fletcher et al. 2015 (V)",
    "T11_T12": "Fletcher et al. 2015 T4-5/T10-11 extrapolated linearly (interpolated)",
    "T12_L1": "mean of T11-T12 and L1-L2 (modelling choice)",
}
for _j in ("T5_T6", "T6_T7", "T7_T8", "T8_T9", "T9_T10"):
    DISC_SRC[_j] = "Fletcher et al. 2015 T4-5 2.7 / T10-11 5.4 (V), linear (interpolated)"
for _j in LUMBAR:
    DISC_SRC[_j] = "middle disc height, MRI study, Anatomical Sciences Journal (V; sex not split)"

# --------------------------------------------------------------------------------------
# Flexion axis (REFERENCE 2c; seed 004: "lies closer to the bottom vertebra"), status U.
# Position relative to the centre of the disc, [x forward, z up], mm. Rule (modelling
# choice, unconfirmed): on the superior endplate of the vertebra below the disc,
# z = -0.5 x disc height, and at the middle of the posterior half of that vertebra's body,
# x = -0.25 x its depth. The vertebra below L5_S1 is S1, whose depth is not in the
# references: L5's depth is used. The lumbar location is Pearcy & Bogduk's as commonly
# cited (U); the thoracic levels carry the same rule with no data of their own.
# --------------------------------------------------------------------------------------

AXIS_X_FRACTION = -0.25  # of the depth of the vertebra below
AXIS_Z_FRACTION = -0.5  # of the disc height


def build() -> dict:
    rest, ratio = rest_flexion()
    sizes = vertebra_sizes()
    depth_below = {j: sizes[LOWER[j] if LOWER[j] in sizes else "L5"][0][0] for j in JOINTS}
    joints = []
    for j in JOINTS:
        fl, ex, lb, ar = rom(j)
        r0 = rest[j]
        h = BB.DISC_HEIGHTS_MM[j]
        fe_, lb_, ar_ = ROM[j]
        share = flexion_share(j)
        if j == "C7_T1":
            rom_src = f"ROM F+E {fe_} / LB {lb_} / AR {ar_}: REFERENCE 1b (S), White & Panjabi 1990"
        else:
            rom_src = (
                f"ROM F+E {fe_} / LB {lb_} / AR {ar_}: White & Panjabi 1990 representative "
                "values, REFERENCE 1a (U)"
            )
        if j in THORACIC[:-1]:
            rest_src = "kyphosis 40 T1-T12 (AO, V), half-sine distribution, apex T6-T7 (DeWald, V)"
        elif j in ("T11_T12", "T12_L1"):
            rest_src = "T11-L1 straight (AO 0, Spine Secrets 'essentially straight', V)"
        elif j in ("L4_L5", "L5_S1"):
            rest_src = f"lordosis {-r0:g} (AO, V)"
        elif j in LUMBAR:
            rest_src = (
                "lordosis 60 L1-S1 (AO / Spine Secrets, V) minus L4-L5 and L5-S1; geometric "
                f"progression L1-L2..L4-L5, ratio {ratio:.4f} (modelling choice)"
            )
        else:
            rest_src = "0 (modelling choice)"
        lower = LOWER[j] if LOWER[j] != "S1" else "L5 (for S1)"
        src = (
            f"rest: {rest_src}; {rom_src}, flexion {share:.0%} of F+E, limits = rest + range; "
            f"disc {h:g} mm: {DISC_SRC[j]}; flexion axis: x = -0.25 x depth of {lower}, "
            "z = -0.5 x disc height (superior endplate of the vertebra below, posterior half; "
            "Pearcy & Bogduk 1988 as commonly cited, U; modelling choice)"
        )
        joints.append(
            {
                "name": j,
                "segment": SEGMENT[j],
                "rest_deg": [rnd(r0, DEG), 0.0, 0.0],
                "limits_deg": {
                    "flexion": [rnd(r0 - ex, DEG), rnd(r0 + fl, DEG)],
                    "axial": [rnd(-ar, DEG), rnd(ar, DEG)],
                    "lateral": [rnd(-lb, DEG), rnd(lb, DEG)],
                },
                "disc_height_mm": rnd(h, MM),
                "flexion_axis_offset_mm": [
                    rnd(AXIS_X_FRACTION * depth_below[j], MM),
                    rnd(AXIS_Z_FRACTION * h, MM),
                ],
                "source": src,
            }
        )
    vertebrae = [{"name": v, "size_mm": sizes[v][0], "source": sizes[v][1]} for v in VERTEBRAE]
    return {
        "schema": SCHEMA,
        "sources": SOURCES,
        "angles": ANGLES,
        "joints": joints,
        "vertebrae": vertebrae,
    }


# --------------------------------------------------------------------------------------
# Checks
# --------------------------------------------------------------------------------------


def check(spine: dict) -> dict[str, tuple[float, float]]:
    """Assert the database's invariants; return the (min, max) totals per rotation."""
    js, vs = spine["joints"], spine["vertebrae"]
    assert [j["name"] for j in js] == JOINTS and len(js) == 18
    assert JOINTS[0] == "C7_T1" and JOINTS[12] == "T12_L1" and JOINTS[-1] == "L5_S1"
    assert [v["name"] for v in vs] == VERTEBRAE and len(vs) == 17
    assert [j["segment"] for j in js] == ["neck"] + VERTEBRAE
    by = {j["name"]: j for j in js}
    for j in js:
        for k, rot in enumerate(("flexion", "axial", "lateral")):
            lo, hi = j["limits_deg"][rot]
            assert lo < j["rest_deg"][k] < hi, (j["name"], rot)
        assert j["rest_deg"][1] == 0.0 and j["rest_deg"][2] == 0.0
        x, z = j["flexion_axis_offset_mm"]
        assert x < 0 and z < 0  # behind the disc centre, closer to the bottom vertebra
    kyph = sum(by[j]["rest_deg"][0] for j in THORACIC)
    lord = sum(by[j]["rest_deg"][0] for j in LUMBAR)
    assert abs(kyph - KYPHOSIS_DEG) < 1e-9, kyph
    assert abs(lord + LORDOSIS_DEG) < 1e-9, lord
    assert by["T11_T12"]["rest_deg"][0] + by["T12_L1"]["rest_deg"][0] == TL_JUNCTION_DEG
    assert by["L4_L5"]["rest_deg"][0] == -L4_L5_DEG and by["L5_S1"]["rest_deg"][0] == -L5_S1_DEG
    lum = [by[j]["rest_deg"][0] for j in LUMBAR]
    assert all(a > b for a, b in zip(lum, lum[1:])), "lordosis must increase caudally"
    th = [by[j]["rest_deg"][0] for j in THORACIC]
    apex = THORACIC.index(KYPHOSIS_APEX)
    assert th[0] > 0 and th.index(max(th)) == apex
    assert all(a < b for a, b in zip(th[:apex], th[1 : apex + 1]))
    assert all(a > b for a, b in zip(th[apex:], th[apex + 1 :]))

    # the deviation from rest equals the vertebra (and neck) limits of the default bodies
    for path in sorted(DATA.glob("body_*.json")):
        body = json.loads(path.read_text(encoding="utf-8"))
        seg = {s["name"]: s for s in body["segments"]}
        for j in js:
            lim = seg[j["segment"]]["limits"]
            r0 = j["rest_deg"][0]
            dev_fl = [rnd(v - r0, DEG) for v in j["limits_deg"]["flexion"]]
            assert dev_fl == lim["swing_y_deg"], (path.name, j["name"], dev_fl)
            assert j["limits_deg"]["lateral"] == lim["swing_x_deg"], (path.name, j["name"])
            assert j["limits_deg"]["axial"] == lim["twist_deg"], (path.name, j["name"])
        print(f"checked {path.name}: spine limits - rest == vertebra and neck limits")

    totals = {}
    for rot in ("flexion", "axial", "lateral"):
        totals[rot] = (
            rnd(sum(j["limits_deg"][rot][0] for j in js), DEG),
            rnd(sum(j["limits_deg"][rot][1] for j in js), DEG),
        )
    return totals


def main() -> None:
    spine = build()
    totals = check(spine)
    OUT.write_text(BB.dumps(spine) + "\n", encoding="utf-8")
    rest = {j["name"]: j["rest_deg"][0] for j in spine["joints"]}
    print(f"wrote {OUT} ({len(spine['joints'])} joints, {len(spine['vertebrae'])} vertebrae)")
    print("rest flexion:", ", ".join(f"{k} {v:g}" for k, v in rest.items()))
    for rot, (lo, hi) in totals.items():
        print(f"sum of {rot} limits: [{lo:g}, {hi:g}]")


if __name__ == "__main__":
    main()
