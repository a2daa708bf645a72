"""Joint limits for measured motion (docs/design.md, section 7): the anatomical maximum of
each range, not the comfortable one the default bodies carry.

A reach asks what a person would comfortably do, so the body files hold typical ranges. A
marker fit asks where a person was: a limit there only hides what the markers saw (the thighs
of the shipped walk stopped at the default 15 degrees of hip extension in late stance, the
markers went further). The fits (`scale_and_register`, `fit_motion`) therefore widen each limb
range to the largest adult figure of the references (data/README.md, "Joint ranges"; Norkin &
White, Measurement of Joint Motion, Appendix Table A.1; Merck Manual, Normal Values for Range
of Motion of Joints, Table 1; the VA schedule 38 CFR 4.71, as reproduced). The spine, the
neck and the head keep their ranges (segmental figures already); the pelvis stays rigid.

Values are the left side's, in degrees, in the body file's convention (data/SCHEMA.md):
swing_x (left: - adduction, + abduction; the wrist: - flexion, + extension), swing_y
(- extension, + flexion; the knee and the ankle: - flexion / plantar flexion), the twist
(left: - external, + internal rotation) and the cone; the right side mirrors swing_x and the
twist.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._body import Body

LIMITS = ("motion", "body")  # the fits' choices: these ranges, or the body's own
# Side-free segment name -> (swing_x, swing_y, twist, cone) in degrees, None: unchanged.
MOTION_RANGES: dict[str, tuple] = {
    # Modelling choice: no reference gives the shoulder girdle's range. 20 degrees (the
    # default) cannot register a T-pose static trial for a walk: the acromia are 342 mm apart
    # with the arms held out and 419 mm while walking, the clavicles retracted and elevated.
    "clavicle": ((-40, 40), (-40, 40), None, 40),
    # Flexion 180 and abduction 180: AAOS (the larger figures of Table A.1 pass the half
    # turn, where a swing is not unique); extension 70, internal rotation 94 and external
    # rotation 108: Macedo & Magee (Table A.1); adduction 30 kept (modelling choice).
    "upper_arm": ((-30, 180), (-70, 180), (-108, 94), None),
    # Elbow flexion 160, pronation 90, supination 90: Merck Manual Table 1.
    "forearm": (None, (0, 160), (-90, 90), None),
    # Wrist flexion 93 and extension 86: Macedo & Magee (Table A.1); ulnar deviation
    # (adduction) 65 and radial deviation (abduction) 25: Merck Manual Table 1; the cone 95
    # (modelling choice: it admits the 93 degrees of flexion).
    "hand": ((-93, 86), (-65, 25), None, 95),
    # Hip extension 30 and external rotation 60: 38 CFR 4.71; flexion 125, abduction 45,
    # internal rotation 45: Merck Manual Table 1; adduction 25: 38 CFR 4.71.
    "thigh": ((-25, 45), (-30, 125), (-60, 45), None),
    # Knee flexion 140: 38 CFR 4.71 (Merck: 130).
    "shank": (None, (-140, 0), None, None),
    # Plantar flexion 50, dorsiflexion 20, inversion 35, eversion 25: Merck Manual Table 1,
    # the default's already.
    "foot": (None, (-50, 20), (-35, 25), None),
}


def motion_limits(body: Body) -> Body:
    """The body with `MOTION_RANGES` for its limbs (module docstring), each interval the
    union of the body's own and the table's (never narrower than the body's: a default
    range past a reference figure stays); segments the table does not name keep their
    limits. Idempotent."""
    lo = np.array(body.swing_lo, dtype=float)
    hi = np.array(body.swing_hi, dtype=float)
    cone = np.array(body.swing_max, dtype=float)
    t_lo = np.array(body.twist_lo, dtype=float)
    t_hi = np.array(body.twist_hi, dtype=float)
    for side, sign in (("left", 1.0), ("right", -1.0)):
        for part, (sx, sy, tw, swing_max) in MOTION_RANGES.items():
            name = f"{side}_{part}"
            if name not in body.segment_names:
                continue
            i = body.segment_index(name)
            if sx is not None and body.limit_kind[i] != "hinge":  # a hinge keeps w_x = 0
                lo[i, 0], hi[i, 0] = _wider((lo[i, 0], hi[i, 0]), _mirrored(sx, sign))
            if sy is not None:
                lo[i, 1], hi[i, 1] = _wider((lo[i, 1], hi[i, 1]), np.radians(sy))
            if tw is not None:
                t_lo[i], t_hi[i] = _wider((t_lo[i], t_hi[i]), _mirrored(tw, sign))
            if swing_max is not None:
                cone[i] = max(cone[i], np.radians(swing_max))
    dtype = body.lengths.dtype
    arrays = tuple(jnp.asarray(a, dtype) for a in (lo, hi, cone, t_lo, t_hi))
    return eqx.tree_at(
        lambda b: (b.swing_lo, b.swing_hi, b.swing_max, b.twist_lo, b.twist_hi), body, arrays
    )


def _wider(own, table) -> tuple[float, float]:
    """The union of two intervals: a body whose own range passes a table figure keeps it."""
    return min(own[0], table[0]), max(own[1], table[1])


def _mirrored(interval, sign: float) -> tuple[float, float]:
    """A left-side interval (degrees) in radians for the side of `sign` (-1: mirrored)."""
    a, b = np.radians(interval)
    return (a, b) if sign > 0 else (-b, -a)
