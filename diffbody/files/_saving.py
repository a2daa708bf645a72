"""Writing a body, and its spine database, as the files `load_body` and `load_spine` read
(schemas in data/SCHEMA.md)."""

import json
from pathlib import Path

import jax
import numpy as np

from .._body import Body, Spine
from ._schema import DEFAULT_SWING_MAX_DEG, SCHEMA, SPINE_ROTATIONS, SPINE_SCHEMA


def _deg(x) -> float:
    return float(np.degrees(float(x)))


def _limit_deg(x) -> float:
    """A limit angle in degrees; +-180 stays +-180 when it arrives as float32's pi
    (180.000005 degrees), which the schema's [-180, 180] would refuse on loading."""
    d = _deg(x)
    return float(np.copysign(180.0, d)) if 180.0 < abs(d) <= 180.0 + 1e-4 else d


def _limits_doc(body: Body, i: int) -> dict:
    """The stop function of segment i as a body file's `limits` object (degrees)."""
    kind = body.limit_kind[i]
    if kind == "free":
        return {"kind": "free"}
    lo, hi = np.asarray(body.swing_lo[i]), np.asarray(body.swing_hi[i])
    twist = [_limit_deg(body.twist_lo[i]), _limit_deg(body.twist_hi[i])]
    smax = _limit_deg(body.swing_max[i])
    if kind == "cone":
        return {"kind": "cone", "swing_max_deg": smax, "twist_deg": twist}
    doc = {"kind": kind}
    if kind == "box":
        doc["swing_x_deg"] = [_limit_deg(lo[0]), _limit_deg(hi[0])]
    doc["swing_y_deg"] = [_limit_deg(lo[1]), _limit_deg(hi[1])]
    if kind == "box" and abs(smax - DEFAULT_SWING_MAX_DEG) > 1e-9:
        doc["swing_max_deg"] = smax
    doc["twist_deg"] = twist
    return doc


def body_document(body: Body, spine_file: str | None = None) -> dict:
    """The body as a `diffbody.body/1` document (data/SCHEMA.md); `spine_file` names its
    spine database relative to the body file."""
    # On the host first: indexing a device array compiles a small program per shape.
    body = jax.tree.map(np.asarray, body)
    origins, radii = np.asarray(body.sphere_origins), np.asarray(body.sphere_radii)
    dirs, seg_of = np.asarray(body.feature_directions), np.asarray(body.sphere_segment)
    features: dict[int, list] = {}
    for name, k, d in zip(body.feature_names, body.feature_sphere, dirs):
        features.setdefault(k, []).append({"name": name.split(".", 1)[1], "direction": d.tolist()})
    segments = []
    for i in range(1, body.n_segments):
        spheres = []
        for k in np.flatnonzero(seg_of == i):
            s = {"origin": origins[k].tolist(), "radius": float(radii[k])}
            if k in features:
                s["features"] = features[k]
            spheres.append(s)
        segments.append(
            {
                "name": body.segment_names[i],
                "proximal": body.joint_names[body.proximal_joint[i]],
                "distal": body.joint_names[body.distal_joint[i]],
                "length": float(body.lengths[i]),
                "direction": np.asarray(body.R_socket_rest[i][:, 2]).tolist(),
                "standard_orientation": body.standard_kind[i],
                "limits": _limits_doc(body, i),
                "mass": float(body.masses[i]),
                "centroid": np.asarray(body.centroids[i]).tolist(),
                "spheres": spheres,
            }
        )
    doc = {
        "schema": SCHEMA,
        "name": body.name,
        "description": f"written by diffbody from {body.source}",
        "sources": [body.source],
        "root_joint": body.joint_names[body.default_root_joint],
        "segments": segments,
    }
    if spine_file is not None:
        doc["spine"] = spine_file
    return doc


def spine_document(spine: Spine) -> dict:
    """The spine database as a `diffbody.spine/1` document (data/SCHEMA.md)."""
    spine = jax.tree.map(np.asarray, spine)
    rest, lo, hi = (np.degrees(np.asarray(a)) for a in (spine.rest, spine.lower, spine.upper))
    joints = [
        {
            "name": name,
            "segment": seg,
            "rest_deg": rest[k].tolist(),
            "limits_deg": {r: [lo[k, a], hi[k, a]] for a, r in enumerate(SPINE_ROTATIONS)},
            "disc_height_mm": float(spine.disc_heights[k]) * 1000.0,
            "flexion_axis_offset_mm": (np.asarray(spine.flexion_axis_offsets[k]) * 1000).tolist(),
        }
        for k, (name, seg) in enumerate(zip(spine.joint_names, spine.segment_names))
    ]
    for j in joints:
        j["limits_deg"] = {r: [float(x) for x in v] for r, v in j["limits_deg"].items()}
    sizes = np.asarray(spine.vertebra_sizes) * 1000.0
    return {
        "schema": SPINE_SCHEMA,
        "initiator": spine.joint_names[spine.initiator],
        "joints": joints,
        "vertebrae": [
            {"name": v, "size_mm": sizes[k].tolist()} for k, v in enumerate(spine.vertebra_names)
        ],
    }


def save_body(body: Body, path: str | Path) -> Path:
    """Write a body file that `load_body` reads back to the same body (the enclosures
    recomputed as the smallest). A body with a spine database also gets `<stem>.spine.json`
    beside it, which the body file names. Returns the path written."""
    path = Path(path)
    spine_file = None
    if body.spine is not None:
        spine_file = f"{path.stem}.spine.json"
        (path.parent / spine_file).write_text(json.dumps(spine_document(body.spine), indent=1))
    path.write_text(json.dumps(body_document(body, spine_file), indent=1))
    return path
