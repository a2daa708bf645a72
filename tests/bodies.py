"""A small body document covering every kind of segment, for tests that build bodies, and
spine databases of other lengths built from the shipped one."""

import copy
import json

import numpy as np

from diffbody.files._data_files import data_file


def _sphere(origin, radius, features=()):
    s = {"origin": list(origin), "radius": radius}
    if features:
        s["features"] = [{"name": n, "direction": list(d)} for n, d in features]
    return s


FIXED = {"kind": "box", "swing_x_deg": [0, 0], "swing_y_deg": [0, 0], "twist_deg": [0, 0]}

MINI = {
    "schema": "diffbody.body/1",
    "name": "mini",
    "sources": ["synthetic test body"],
    "root_joint": "hip",
    "segments": [
        {
            "name": "trunk",
            "proximal": "hip",
            "distal": "neck",
            "length": 0.5,
            "direction": [0, 0, 1],
            "limits": {
                "kind": "box",
                "swing_x_deg": [-30, 30],
                "swing_y_deg": [-20, 60],
                "twist_deg": [-40, 40],
            },
            "mass": 30.0,
            "centroid": [0.02, 0, 0.25],
            "spheres": [_sphere([0.05, 0, 0.1], 0.12), _sphere([0.05, 0, 0.35], 0.14)],
        },
        {
            "name": "left_clavicle",
            "proximal": "neck",
            "distal": "left_shoulder",
            "length": 0.18,
            "direction": [0, 1, -0.2],
            "limits": {"kind": "cone", "swing_max_deg": 20, "twist_deg": [0, 0]},
            "mass": 1.0,
            "centroid": [0, 0, 0.09],
            "spheres": [_sphere([0, 0, 0.1], 0.05)],
        },
        {
            "name": "left_upper_arm",
            "proximal": "left_shoulder",
            "distal": "left_elbow",
            "length": 0.3,
            "direction": [0, 0, -1],
            "standard_orientation": "left_arm",
            "limits": {
                "kind": "box",
                "swing_x_deg": [-30, 170],
                "swing_y_deg": [-60, 167],
                "swing_max_deg": 175,
                "twist_deg": [-90, 70],
            },
            "mass": 2.0,
            "centroid": [0, 0, 0.15],
            "spheres": [
                _sphere([0, 0, 0.0], 0.05),
                _sphere([0.03, 0.02, 0.15], 0.045),
                _sphere([0, 0, 0.3], 0.04, [("elbow", [-1, 0, 0])]),
            ],
        },
        {
            "name": "left_forearm",
            "proximal": "left_elbow",
            "distal": "left_wrist",
            "length": 0.26,
            "direction": [0, 0, -1],
            "limits": {"kind": "hinge", "swing_y_deg": [0, 150], "twist_deg": [-80, 80]},
            "mass": 1.5,
            "centroid": [0, 0, 0.12],
            "spheres": [
                _sphere([0.02, 0.01, 0.05], 0.04),
                _sphere([0.01, 0.02, 0.26], 0.03, [("palm", [0, 1, 0])]),
            ],
        },
        {
            "name": "left_thigh",
            "proximal": "hip",
            "distal": "left_knee",
            "length": 0.42,
            "direction": [0, 0.1, -1],
            "limits": FIXED,
            "mass": 8.0,
            "centroid": [0, 0, 0.2],
            "spheres": [_sphere([0, 0, 0.2], 0.08), _sphere([0, 0, 0.42], 0.06)],
        },
    ],
}


def mini_doc() -> dict:
    """A fresh, mutable copy of the small body document."""
    return copy.deepcopy(MINI)


def write(doc, path) -> str:
    path.write_text(json.dumps(doc))
    return str(path)


def random_pose(body, rng, *, within_limits=True, position=None):
    """A random pose: inside the joint limits (swing box within the cone, twist in range), or
    anywhere on the sphere of directions with twists in [-1, 1] rad."""
    import jax.numpy as jnp

    import diffbody as db

    n = body.n_segments
    if within_limits:
        lo, hi = np.asarray(body.swing_lo), np.asarray(body.swing_hi)
        w = lo + (hi - lo) * rng.uniform(size=(n, 2))
        norm = np.linalg.norm(w, axis=1)
        smax = np.asarray(body.swing_max)
        w *= np.minimum(1.0, smax / np.maximum(norm, 1e-300))[:, None]
        tlo, thi = (
            np.clip(np.asarray(body.twist_lo), -np.pi, None),
            np.clip(np.asarray(body.twist_hi), None, np.pi),
        )
        tau = tlo + (thi - tlo) * rng.uniform(size=n)
        w[0] = rng.uniform(-0.5, 0.5, size=2)  # whole body: a moderate tilt
        angles = db.angles_from_swing(body, jnp.asarray(w), jnp.asarray(tau))
    else:
        angles = jnp.asarray(
            np.stack(
                [rng.uniform(-np.pi, np.pi, n), rng.uniform(0, np.pi, n), rng.uniform(-1, 1, n)], -1
            )
        )
    pos = body.rest_position if position is None else jnp.asarray(position)
    return db.Pose(position=jnp.asarray(pos), angles=angles)


def lumped_spine_doc(n: int) -> dict:
    """A spine database of `n` joints built from the shipped one's data alone (a shorter
    chain, as a child's or an animal's, for the spine tests): its 18 joints in `n`
    contiguous groups, each group one joint that stands for its levels (limits, rest angles
    and disc heights summed, flexion-axis offsets averaged), moving the group's first
    segment; the initiator the group holding the shipped one's (T12-L1)."""
    doc = json.loads(data_file("spine.json").read_text())
    joints, sizes = doc["joints"], {v["name"]: v["size_mm"] for v in doc["vertebrae"]}
    groups = np.array_split(np.arange(len(joints)), n)
    out = []
    for group in groups:
        members = [joints[k] for k in group]
        first = members[0]
        limits = {
            rot: [sum(m["limits_deg"][rot][i] for m in members) for i in (0, 1)]
            for rot in first["limits_deg"]
        }
        out.append(
            dict(
                name="+".join(m["name"] for m in members),
                segment=first["segment"],
                rest_deg=list(np.sum([m["rest_deg"] for m in members], axis=0)),
                limits_deg=limits,
                disc_height_mm=sum(m["disc_height_mm"] for m in members),
                flexion_axis_offset_mm=list(
                    np.mean([m["flexion_axis_offset_mm"] for m in members], axis=0)
                ),
            )
        )
    initiator = next(j["name"] for j in out if "T12_L1" in j["name"].split("+"))
    vertebrae = [dict(name=j["segment"], size_mm=sizes[j["segment"]]) for j in out[1:]]
    return dict(schema=doc["schema"], initiator=initiator, joints=out, vertebrae=vertebrae)
