"""Shared test helpers: an independent plain-NumPy forward kinematics for diffbody.

This module does not import JAX or diffbody. It reads a body file (data/SCHEMA.md) directly
and walks the tree with NumPy, written from the source documents (seed 000, docs/design.md,
sections 1-4) and not from diffbody's code, so the tests can check diffbody against it.

Conventions (the contract the reference and diffbody share):

- Rz(a) = [[c, -s, 0], [s, c, 0], [0, 0, 1]], Ry(a) = [[c, 0, s], [0, 1, 0], [-s, 0, c]].
- Cross of axes C(d) of a standard-position direction d: Z = d; X = (d_z, 0, -d_x)
  normalised, in the vertical plane perpendicular to world Y, with a positive forward
  component (pointing up if Z is forward or backward); X = (1, 0, 0) if d = +-Y; Y = Z x X.
- A segment's socket frame is its parent's twisted frame turned by C(parent)^T, so in the
  standard position every socket is the world frame. The implicit "whole_body" segment
  (length 0, rest direction +Z, C = I, "swing") hangs from the world at the root joint.
- Base frame in the socket: limbs Rz(theta) Ry(phi) Rz(s(theta, phi)) with seed 000's
  standard-orientation twist s; other segments the swing (smallest rotation) taking the rest
  direction to the current one, applied to C(rest direction). The twisted frame is the base
  frame turned by Rz(tau); spheres and centroids turn by Rz(tau * clip(z / length, 0, 1)).
"""

import json
import math
from pathlib import Path

import numpy as np

WHOLE_BODY = "whole_body"
LIMBS = ("left_arm", "right_arm", "left_leg", "right_leg")


# --- body files --------------------------------------------------------------------------------
def load_json_body(path: str | Path) -> dict:
    """Read a body file (schema diffbody.body/1) as a plain dict, without diffbody."""
    with open(path, encoding="utf-8") as f:
        return json.load(f)


# --- elementary rotations ----------------------------------------------------------------------
def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by `angle` about the unit vector `axis`, built as the change of basis
    (axis, u, v) -> rotate in the (u, v) plane -> back (not Rodrigues' closed form)."""
    k = _unit(axis)
    # Any unit vector u perpendicular to k, then v = k x u completes a right-handed basis.
    helper = np.eye(3)[int(np.argmin(np.abs(k)))]
    u = _unit(np.cross(k, helper))
    v = np.cross(k, u)
    basis = np.column_stack([u, v, k])  # local frame whose Z is the axis
    return basis @ rot_z(angle) @ basis.T


def swing_rotation(a: np.ndarray, b: np.ndarray, antipodal_axis=None) -> np.ndarray:
    """The smallest rotation taking unit vector a to unit vector b: about a x b by the angle
    between them; the identity when they coincide.

    Exactly opposite vectors have no unique answer; there the rotation is by pi about
    `antipodal_axis` (made perpendicular to a), and without one it raises. A tiny but
    nonzero a x b still gives its own axis (normalising keeps its direction in floating
    point), i.e. the limit along the great circle through a and b.
    """
    a, b = _unit(a), _unit(b)
    axis = np.cross(a, b)
    n = np.linalg.norm(axis)
    if n > 0.0:
        return axis_angle(axis / n, math.atan2(n, float(np.dot(a, b))))
    if np.dot(a, b) > 0:
        return np.eye(3)
    if antipodal_axis is None:
        raise ValueError("swing_rotation: opposite directions and no axis given")
    k = np.asarray(antipodal_axis, dtype=float)
    return axis_angle(k - np.dot(k, a) * a, math.pi)


def cross_of_axes(d) -> np.ndarray:
    """Seed 000's cross of axes for a standard-position direction d (columns X, Y, Z)."""
    z = _unit(d)
    x = np.array([z[2], 0.0, -z[0]])
    n = np.linalg.norm(x)
    if n < 1e-12:  # d = +-Y: X forward
        x = np.array([1.0, 0.0, 0.0])
    else:
        x = x / n
        if x[0] < -1e-12 or (abs(x[0]) <= 1e-12 and x[2] < 0):
            x = -x
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


# --- seed 000's standard orientation -----------------------------------------------------------
def _sgn_seam(x: float) -> float:
    """sgn for the seam at theta = 225 deg: the +1 branch on the seam itself."""
    return 1.0 if x >= 0 else -1.0


def left_arm_twist_deg(theta_deg: float, phi_deg: float) -> float:
    """Seed 000's five-piece standard orientation twist t(theta, phi) of the left arm (deg).

    Typed again from the seed's table; theta is taken into [-90, 270). Rows:

        theta [-90, 90],  phi [0, 90]:    t = 180 - theta * (1 - phi/90)
        theta [-90, 90],  phi [90, 180]:  t = -180 * (1 - theta/90) + (phi - 270) * (theta/90)
        theta [90, 270],  phi [90, 180]:  t = (theta - 180) * (1 + (180 - phi)/90)
        theta [90, 180],  phi [0, 90]:    t = 2 * (theta - 180) * phi/90
                                              - (180 + theta) * (1 - phi/90)
        theta [180, 270], phi [0, 90]:    t = (180 - theta) * (1 - 3 phi/90)
                                              + sgn(225 - theta) * 360 * phi/90
    """
    th = (float(theta_deg) + 90.0) % 360.0 - 90.0
    ph = float(phi_deg)
    if th < 90.0:
        if ph < 90.0:
            return 180.0 - th * (1.0 - ph / 90.0)
        return -180.0 * (1.0 - th / 90.0) + (ph - 270.0) * (th / 90.0)
    if ph >= 90.0:
        return (th - 180.0) * (1.0 + (180.0 - ph) / 90.0)
    if th < 180.0:
        return 2.0 * (th - 180.0) * ph / 90.0 - (180.0 + th) * (1.0 - ph / 90.0)
    return (180.0 - th) * (1.0 - 3.0 * ph / 90.0) + _sgn_seam(225.0 - th) * 360.0 * ph / 90.0


def left_leg_twist_deg(theta_deg: float, phi_deg: float) -> float:
    """Standard orientation twist of the left leg (deg), theta taken into [-180, 180):
    phi >= 90: theta - 180; phi < 90: 180 - theta + 2 theta phi / 90."""
    th = (float(theta_deg) + 180.0) % 360.0 - 180.0
    ph = float(phi_deg)
    if ph >= 90.0:
        return th - 180.0
    return 180.0 - th + 2.0 * th * ph / 90.0


def right_arm_twist_deg(theta_deg: float, phi_deg: float) -> float:
    """Mirror image of the left arm in the sagittal plane: s(theta, phi) = -left(-theta, phi)."""
    return -left_arm_twist_deg(-float(theta_deg), phi_deg)


def right_leg_twist_deg(theta_deg: float, phi_deg: float) -> float:
    """Mirror image of the left leg: s(theta, phi) = -left_leg(-theta, phi)."""
    return -left_leg_twist_deg(-float(theta_deg), phi_deg)


TWIST_TABLES_DEG = {
    "left_arm": left_arm_twist_deg,
    "right_arm": right_arm_twist_deg,
    "left_leg": left_leg_twist_deg,
    "right_leg": right_leg_twist_deg,
}


def standard_twist(kind: str, theta: float, phi: float) -> float:
    """A limb's standard-orientation twist (rad) for direction (theta, phi) (rad)."""
    phi = min(max(float(phi), 0.0), math.pi)
    return math.radians(TWIST_TABLES_DEG[kind](math.degrees(theta), math.degrees(phi)))


# --- forward kinematics ------------------------------------------------------------------------
def direction(theta: float, phi: float) -> np.ndarray:
    """Unit vector of azimuth theta (about Z from X toward Y) and polar angle phi (from Z)."""
    return np.array(
        [math.sin(phi) * math.cos(theta), math.sin(phi) * math.sin(theta), math.cos(phi)]
    )


def base_in_socket(kind: str, d_rest: np.ndarray, theta: float, phi: float) -> np.ndarray:
    """A segment's untwisted frame in its socket for direction (theta, phi).

    Limbs: Rz(theta) Ry(phi) Rz(s(theta, phi)). Other segments: the swing from the rest
    direction, applied to the rest cross of axes. A swing exactly opposite the rest
    direction (only reachable at a pole, e.g. a forearm at phi = 0) is taken as the limit
    along the meridian of theta from inside [0, pi]; there the swing axis is
    d_rest x (meridian tangent pointing into [0, pi]).
    """
    if kind in LIMBS:
        return rot_z(theta) @ rot_y(phi) @ rot_z(standard_twist(kind, theta, phi))
    tangent = np.array(
        [math.cos(phi) * math.cos(theta), math.cos(phi) * math.sin(theta), -math.sin(phi)]
    )
    inward = tangent if phi < math.pi / 2 else -tangent
    S = swing_rotation(d_rest, direction(theta, phi), antipodal_axis=np.cross(d_rest, inward))
    return S @ cross_of_axes(d_rest)


def _segments(doc: dict) -> list[dict]:
    """The segments with the implicit whole body first, parents before children."""
    root = doc["root_joint"]
    whole = {
        "name": WHOLE_BODY,
        "proximal": None,
        "distal": root,
        "length": 0.0,
        "direction": [0.0, 0.0, 1.0],
        "standard_orientation": "swing",
        "mass": 0.0,
        "centroid": [0.0, 0.0, 0.0],
        "spheres": [],
        "parent": None,
    }
    ordered = [whole]
    by_proximal: dict[str, list[dict]] = {}
    for seg in doc["segments"]:
        by_proximal.setdefault(seg["proximal"], []).append(seg)
    k = 0
    while k < len(ordered):
        parent = ordered[k]
        for child in by_proximal.get(parent["distal"], []):
            ordered.append({**child, "parent": parent["name"]})
        k += 1
    if len(ordered) != len(doc["segments"]) + 1:
        raise ValueError("body file: some segments do not hang from the root joint")
    return ordered


def reference_forward(doc: dict, position, angles_by_segment: dict) -> dict:
    """Plain-NumPy forward kinematics of a body file in a pose.

    Args:
        doc: the parsed body file (`load_json_body`).
        position: (3,) world position of the root joint (m).
        angles_by_segment: segment name -> (theta, phi, tau) (rad), "whole_body" included.

    Returns a dict with "joints" (joint name -> (3,) world position, the root joint
    included), "spheres" (list of (segment name, index within the segment, (3,) world
    centre, radius)), "features" ("segment.feature" -> (3,) world point), "frames_base" and
    "frames_twisted" (segment name -> 3x3 world rotation, columns = axes) and "cog" (3,).
    """
    position = np.asarray(position, dtype=float).reshape(3)
    joints: dict[str, np.ndarray] = {doc["root_joint"]: position.copy()}
    frames_base: dict[str, np.ndarray] = {}
    frames_twisted: dict[str, np.ndarray] = {}
    crosses: dict[str, np.ndarray] = {}
    spheres: list = []
    features: dict[str, np.ndarray] = {}
    weighted = np.zeros(3)
    total_mass = 0.0

    for seg in _segments(doc):
        name = seg["name"]
        d_rest = _unit(seg["direction"])
        crosses[name] = cross_of_axes(d_rest)
        theta, phi, tau = (float(a) for a in angles_by_segment[name])
        if seg["parent"] is None:
            R_world_socket = np.eye(3)
            proximal = position
        else:
            p = seg["parent"]
            R_world_socket = frames_twisted[p] @ crosses[p].T
            proximal = joints[seg["proximal"]]
        kind = seg.get("standard_orientation", "swing")
        R_base = R_world_socket @ base_in_socket(kind, d_rest, theta, phi)
        frames_base[name] = R_base
        frames_twisted[name] = R_base @ rot_z(tau)
        length = float(seg["length"])
        joints[seg["distal"]] = proximal + length * R_base[:, 2]

        def place(local, length=length, tau=tau, proximal=proximal, R_base=R_base):
            """World point of a local point turned by its share of the twist, and the turn."""
            local = np.asarray(local, dtype=float)
            frac = min(max(local[2] / length, 0.0), 1.0) if length > 0 else 0.0
            R = R_base @ rot_z(tau * frac)
            return proximal + R @ local, R

        for k, sph in enumerate(seg["spheres"]):
            centre, R = place(sph["origin"])
            radius = float(sph["radius"])
            spheres.append((name, k, centre, radius))
            for feat in sph.get("features", []):
                normal = R @ _unit(feat["direction"])
                features[f"{name}.{feat['name']}"] = centre + radius * normal
        mass = float(seg["mass"])
        if mass > 0:
            c, _ = place(seg["centroid"])
            weighted += mass * c
            total_mass += mass

    cog = weighted / total_mass if total_mass > 0 else position.copy()
    return {
        "joints": joints,
        "spheres": spheres,
        "features": features,
        "frames_base": frames_base,
        "frames_twisted": frames_twisted,
        "cog": cog,
    }
