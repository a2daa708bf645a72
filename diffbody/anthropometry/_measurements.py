"""Body measurements (docs/design.md, section 7) as differentiable functions of a body's
dimensions, each following its ANSUR II definition (Gordon et al. 2014, NATICK/TR-15/007) as
closely as the sphere model allows: `measure`, `measurements`, `MEASUREMENTS`.

All are taken on the standard position (`rest_points`): heights above the floor (the lowest
sphere), breadths and depths as extents of named segments' spheres, lengths between joints;
span, sitting height and buttock-knee length in closed form in the survey's posture. Each is
the nearest model feature times a calibration factor: the geometric mean, over the two median
bodies (male50, female50), of the median of ANSUR II's even rows (rows 0, 2, 4, ... of each
sex's file) over the body's model value; 1 where the model has the landmark (the body is built
on it). The odd rows are held out: tests/anthropometry/test_anthropometry.py checks the factors
on them, and the anthropometry benchmark, which fits the prior on the even rows, tests on them.
Metres; `weightkg` in kg.
"""

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import Body, unknown_name_error
from ._scaling import rest_points


class Geometry(NamedTuple):
    """The standard position, relative to the floor: joint positions (n_joint, 3), sphere
    centres (n_sph, 3), radii (n_sph,), masses (n_seg,); the body for the names."""

    joints: Array
    centers: Array
    radii: Array
    masses: Array
    body: Body

    def joint(self, name: str) -> Array:
        return self.joints[self.body.joint_index(name)]

    def spheres(self, *segments: str) -> tuple[Array, Array]:
        idx = np.concatenate([self.body.segment_spheres(s) for s in segments])
        return self.centers[idx], self.radii[idx]

    def extent(self, axis: int, *segments: str) -> Array:
        """Outer extent of the segments' spheres along a world axis (m)."""
        c, r = self.spheres(*segments)
        return jnp.max(c[:, axis] + r) - jnp.min(c[:, axis] - r)

    def top(self, *segments: str) -> Array:
        c, r = self.spheres(*segments)
        return jnp.max(c[:, 2] + r)


def geometry(body: Body) -> Geometry:
    """The standard position with the floor (the lowest sphere's bottom) at z = 0."""
    joints, centers = rest_points(body)
    floor = jnp.min(centers[:, 2] - body.sphere_radii)
    down = jnp.asarray([0.0, 0.0, 1.0]) * floor
    return Geometry(joints - down, centers - down, body.sphere_radii, body.masses, body)


def _distance(a: Array, b: Array) -> Array:
    return jnp.sqrt(jnp.sum((a - b) ** 2))


def _span(g: Geometry) -> Array:
    # Arms straight out to the sides: each fingertip lies its straight-arm distance from the
    # shoulder joint, along the line through both shoulder joints.
    reach = sum(
        _distance(g.joint(f"{s}_fingertip"), g.joint(f"{s}_shoulder")) for s in ("left", "right")
    )
    return _distance(g.joint("left_shoulder"), g.joint("right_shoulder")) + reach


def _shoulder_top(g: Geometry) -> Array:
    # The acromion: the top of the shoulder, the upper arm's deltoid cap.
    return g.top("left_upper_arm")


def _sitting_height(g: Geometry) -> Array:
    # Seated, the trunk stands on the buttocks: the thigh's first sphere below the hip joint.
    c, r = g.spheres("left_thigh")
    return g.top("head") - (g.joint("left_hip")[2] - r[0])


def _buttock_knee(g: Geometry) -> Array:
    # Seated with the thigh horizontal: the back of the buttocks (the pelvis spheres behind
    # the hip joint) to the front of the knee (the thigh's last sphere around the knee).
    c, r = g.spheres("pelvis", "left_pelvis", "right_pelvis")
    back = g.joint("left_hip")[0] - jnp.min(c[:, 0] - r)
    _, r_thigh = g.spheres("left_thigh")
    length = _distance(g.joint("left_knee"), g.joint("left_hip"))
    return back + length + r_thigh[-1]


class Measurement(NamedTuple):
    """One ANSUR II measurement: its model value (m, or kg) from the geometry, the
    calibration factor, and how the model takes it."""

    model: Callable[[Geometry], Array]
    calibration: float
    definition: str


# Calibration factors: the geometric mean over male50 and female50 of the median of ANSUR II's
# even rows / the body's model value (module docstring); tests/anthropometry/
# test_anthropometry.py::test_calibration_factors recomputes them, and
# ::test_calibration_holds_on_the_odd_rows checks them on the rows they did not see.
MEASUREMENTS: dict[str, Measurement] = {
    "stature": Measurement(
        lambda g: g.top("head"),
        1.0,
        "vertex (the head's top) to the floor, standing",
    ),
    "weightkg": Measurement(
        lambda g: jnp.sum(g.masses),
        1.0,
        "the sum of the segment masses (kg)",
    ),
    "span": Measurement(
        _span,
        0.972293,
        "fingertip to fingertip, arms straight out: the shoulder joints' distance plus each "
        "straight arm's reach from its shoulder joint",
    ),
    "acromialheight": Measurement(
        _shoulder_top,
        1.003236,
        "acromion to the floor: the top of the upper arm's deltoid cap",
    ),
    "cervicaleheight": Measurement(
        lambda g: g.joint("C7_T1")[2],
        1.0,
        "cervicale (C7's spinous process) to the floor: the C7-T1 joint",
    ),
    "sittingheight": Measurement(
        _sitting_height,
        0.979098,
        "vertex to the seat, sitting: the head's top above the hip joint plus the thigh's "
        "radius below it",
    ),
    "trochanterionheight": Measurement(
        lambda g: g.joint("left_hip")[2],
        1.0,
        "trochanterion to the floor: the hip joint",
    ),
    "kneeheightmidpatella": Measurement(
        lambda g: g.joint("left_knee")[2],
        0.977454,
        "mid-patella to the floor: the knee joint",
    ),
    "lateralfemoralepicondyleheight": Measurement(
        lambda g: g.joint("left_knee")[2],
        1.0,
        "lateral femoral epicondyle to the floor: the knee joint",
    ),
    "tibialheight": Measurement(
        lambda g: g.joint("left_knee")[2],
        0.945364,
        "tibiale (the tibia's upper medial edge) to the floor: the knee joint",
    ),
    "biacromialbreadth": Measurement(
        lambda g: _distance(g.joint("left_shoulder"), g.joint("right_shoulder")),
        1.085023,
        "acromion to acromion: the shoulder joints' distance",
    ),
    "bideltoidbreadth": Measurement(
        lambda g: g.extent(1, "left_upper_arm", "right_upper_arm"),
        1.0,
        "the deltoids' outer breadth: the upper arms' spheres across",
    ),
    "hipbreadth": Measurement(
        lambda g: g.extent(1, "left_pelvis", "right_pelvis"),
        1.0,
        "the hips' breadth, standing: the lateral pelvis spheres across (the hemi-pelvis "
        "links carry the widest sphere of each pelvis ring)",
    ),
    "chestdepth": Measurement(
        lambda g: g.extent(0, "T6", "T7", "T8"),
        1.0,
        "the chest's depth at the nipples: the T6-T8 rings front to back",
    ),
    "shoulderelbowlength": Measurement(
        lambda g: _shoulder_top(g) - g.joint("left_elbow")[2],
        1.099282,
        "acromion to the elbow's bottom, elbow bent: the deltoid cap's top to the elbow joint",
    ),
    "acromionradialelength": Measurement(
        lambda g: _shoulder_top(g) - g.joint("left_elbow")[2],
        1.017512,
        "acromion to radiale: the deltoid cap's top to the elbow joint",
    ),
    "radialestylionlength": Measurement(
        lambda g: _distance(g.joint("left_elbow"), g.joint("left_wrist")),
        1.0,
        "radiale to stylion: elbow joint to wrist joint",
    ),
    "handlength": Measurement(
        lambda g: _distance(g.joint("left_wrist"), g.joint("left_fingertip")),
        1.0,
        "wrist crease to the middle fingertip: wrist joint to fingertip joint",
    ),
    "footlength": Measurement(
        lambda g: g.extent(0, "left_foot"),
        1.0,
        "heel to the longest toe: the foot spheres front to back",
    ),
    "buttockkneelength": Measurement(
        _buttock_knee,
        1.008848,
        "back of the buttocks to the front of the knee, seated: the pelvis spheres behind "
        "the hip joint, the thigh, the knee sphere's radius",
    ),
    "headlength": Measurement(
        lambda g: g.extent(0, "head"),
        0.941994,
        "glabella to opisthocranion: the head spheres front to back",
    ),
}
MEASUREMENT_NAMES = tuple(MEASUREMENTS)
UNITS = {name: "kg" if name == "weightkg" else "m" for name in MEASUREMENT_NAMES}


def check_names(names) -> tuple[str, ...]:
    """The names as a tuple; an unknown one raises KeyError listing the valid names."""
    names = tuple(names)
    for name in names:
        if name not in MEASUREMENTS:
            raise unknown_name_error("measurement", name, MEASUREMENT_NAMES)
    return names


def measure(body: Body, names=MEASUREMENT_NAMES) -> Float[Array, " k"]:
    """The named measurements of a body (m, weightkg in kg), in the order of `names`:
    differentiable with respect to the body's dimensions, jit- and vmap-able (names static).
    """
    names = check_names(names)
    g = geometry(body)
    return jnp.stack([MEASUREMENTS[n].model(g) * MEASUREMENTS[n].calibration for n in names])


def measurements(body: Body, names=MEASUREMENT_NAMES) -> dict[str, float]:
    """The named measurements of a body as a dict of floats (host side)."""
    names = check_names(names)
    values = np.asarray(_measure_jit(body, names))
    return {n: float(v) for n, v in zip(names, values)}


_measure_jit = jax.jit(measure, static_argnums=1)
