"""Loading and validating body files (the schema, with the physical ranges, in
data/SCHEMA.md). Spine databases are read by `_spine_file`, written with bodies by `_saving`.

Every error is a `BodyFileError` (`_data_files`) naming the file, the entry, the field and
what is expected.
"""

import dataclasses
import math
from collections import deque
from pathlib import Path

import equinox as eqx
import numpy as np

from .._body import CENTER_OF_GRAVITY, WHOLE_BODY, Body, rest_geometry
from .._device_arrays import device_array
from .._orientation import LIMBS
from .._rotations import cross_of_axes
from ._data_files import BodyFileError as BodyFileError
from ._data_files import Where, data_file, read_json
from ._data_files import json_object as json_object
from ._saving import body_document as body_document
from ._saving import save_body as save_body
from ._schema import (
    DEFAULT_SWING_MAX_DEG,
    FEATURE_FIELDS,
    LENGTH_M,
    LIMIT_FIELDS,
    MASS_KG,
    MIN_SWING_MAX_DEG,
    OPTIONAL_LIMIT_FIELDS,
    POSITION_M,
    SCHEMA,
    TOP_FIELDS,
)
from ._spine_file import load_spine

# The `X as X` imports above are re-exports: code elsewhere imports BodyFileError, json_object,
# body_document and save_body (and data_file, Where, load_spine) from here as well as from
# their homes, `_data_files`, `_saving` and `_spine_file`.


def _limits(where: Where, seg: dict) -> tuple[str, list[float], list[float], float, float, float]:
    """Parse a segment's limits into (kind, swing_lo, swing_hi, swing_max, twist_lo, twist_hi)."""
    lim = seg["limits"]
    w = Where(where.path, where.entry + ", limits")
    if not isinstance(lim, dict):
        raise where.fail("limits", f"must be a JSON object, got {type(lim).__name__}")
    kind = lim.get("kind")
    if not isinstance(kind, str) or kind not in LIMIT_FIELDS:
        raise w.fail("kind", f"must be one of {sorted(LIMIT_FIELDS)}, got {kind!r}")
    w.fields(
        lim, LIMIT_FIELDS[kind] | {"kind"}, OPTIONAL_LIMIT_FIELDS.get(kind, set()) | {"source"}
    )
    if kind == "free":
        return kind, [-math.pi] * 2, [math.pi] * 2, math.pi, -math.inf, math.inf
    tlo, thi = w.range_deg(lim, "twist_deg")
    if kind == "cone" or "swing_max_deg" in lim:
        smax_deg = w.number(lim, "swing_max_deg")
        if smax_deg >= 180:
            raise w.fail("swing_max_deg", f"must be < 180 degrees, got {smax_deg}")
        if smax_deg < MIN_SWING_MAX_DEG:
            raise w.fail(
                "swing_max_deg",
                f"must be >= {MIN_SWING_MAX_DEG} degrees, got {smax_deg:g}; to fix the "
                "direction use kind 'box' with [0, 0] swing ranges",
            )
        smax = math.radians(smax_deg)
    else:
        smax = math.radians(DEFAULT_SWING_MAX_DEG)
    if kind == "cone":
        return kind, [-smax, -smax], [smax, smax], smax, tlo, thi
    ylo, yhi = w.range_deg(lim, "swing_y_deg")
    xlo, xhi = (0.0, 0.0) if kind == "hinge" else w.range_deg(lim, "swing_x_deg")
    return kind, [xlo, ylo], [xhi, yhi], smax, tlo, thi


def _enclosure(origins: np.ndarray, radii: np.ndarray) -> tuple[float, float]:
    """Smallest sphere centred on the segment axis (0, 0, z) that holds all spheres.

    Seed 000's enclosure is "the minimum sphere which includes the entire surface". We keep
    its centre on the segment's Z axis: a twist turns the spheres about that axis, so this
    sphere stays an enclosure in every posture. f(z) = max_k |(rho_k, z_k - z)| + r_k is
    convex, so a golden-section search finds its minimum to machine precision.
    """
    if len(radii) == 0:
        return 0.0, 0.0
    rho2 = np.sum(origins[:, :2] ** 2, axis=1)

    def f(z: float) -> float:
        return float(np.max(np.sqrt(rho2 + (origins[:, 2] - z) ** 2) + radii))

    lo, hi = float(origins[:, 2].min()), float(origins[:, 2].max())
    g = (math.sqrt(5) - 1) / 2
    a, b = lo + (1 - g) * (hi - lo), lo + g * (hi - lo)
    fa, fb = f(a), f(b)
    for _ in range(200):
        if fa <= fb:
            hi, b, fb = b, a, fa
            a = lo + (1 - g) * (hi - lo)
            fa = f(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + g * (hi - lo)
            fb = f(b)
        if hi - lo < 1e-15:
            break
    z = (lo + hi) / 2
    return z, f(z)


def _resolve(path: str | Path | None, variant: str) -> Path:
    if path is not None:
        return Path(path)
    try:
        return data_file(f"body_{variant}.json")
    except FileNotFoundError:
        folder = data_file("SCHEMA.md").parent
        found = sorted(p.stem.removeprefix("body_") for p in folder.glob("body_*.json"))
        raise ValueError(
            f"load_body: unknown variant {variant!r}; available variants: {found}"
        ) from None


def load_body(path: str | Path | None = None, *, variant: str = "male50") -> Body:
    """Load and validate a body file (schema: data/SCHEMA.md).

    Args:
        path: a body JSON file; None loads the embedded default body `variant`.
        variant: the embedded body to load when `path` is None: "male50" or "female50"
            (ANSUR II medians of each sex).

    Raises:
        BodyFileError: the file is malformed; the message names the file, the entry, the
            field and what is expected.
    """
    path = _resolve(path, variant)
    shown = str(path)
    doc = read_json(path, "body")
    top = Where(shown, "top level")
    top.fields(doc, TOP_FIELDS - {"description", "spine"}, {"description", "spine"})
    if doc["schema"] != SCHEMA:
        raise top.fail("schema", f"must be {SCHEMA!r}, got {doc['schema']!r}")
    name = top.string(doc, "name")
    root_name = top.string(doc, "root_joint")
    if not isinstance(doc["sources"], list) or not all(isinstance(s, str) for s in doc["sources"]):
        raise top.fail("sources", "must be a list of citation strings")
    segs = doc["segments"]
    if not isinstance(segs, list) or not segs:
        raise top.fail("segments", "must be a non-empty list of segment objects")

    parsed = []
    by_name: dict[str, int] = {}
    by_distal: dict[str, int] = {}
    for k, seg in enumerate(segs):
        label = seg.get("name") if isinstance(seg, dict) else None
        where = Where(shown, f"segment {label!r} (segments[{k}])" if label else f"segments[{k}]")
        where.fields(
            seg,
            {
                "name",
                "proximal",
                "distal",
                "length",
                "direction",
                "limits",
                "mass",
                "centroid",
                "spheres",
            },
            {"standard_orientation", "source"},
        )
        nm = where.string(seg, "name")
        if nm in (WHOLE_BODY,):
            raise where.fail("name", f"{nm!r} is reserved for the segment the loader adds")
        if nm in by_name:
            raise where.fail("name", f"duplicate segment name (also segments[{by_name[nm]}])")
        by_name[nm] = k
        prox, dist = where.string(seg, "proximal"), where.string(seg, "distal")
        if dist == root_name:
            raise where.fail("distal", f"the root joint {root_name!r} cannot be a distal joint")
        if dist in by_distal:
            other = segs[by_distal[dist]]["name"]
            raise where.fail(
                "distal",
                f"joint {dist!r} is already the distal joint of segment {other!r}; "
                "every joint ends exactly one segment",
            )
        if dist == CENTER_OF_GRAVITY or prox == CENTER_OF_GRAVITY:
            raise where.fail("proximal", f"{CENTER_OF_GRAVITY!r} is reserved for the loader")
        by_distal[dist] = k
        std = seg.get("standard_orientation", "swing")
        if std != "swing" and std not in LIMBS:
            raise where.fail(
                "standard_orientation", f"must be 'swing' or one of {list(LIMBS)}, got {std!r}"
            )
        direction = where.vector(seg, "direction", unit=True)
        if std != "swing" and np.linalg.norm(direction - [0, 0, -1]) > 1e-6:
            raise where.fail(
                "direction",
                f"a limb with standard_orientation {std!r} must hang straight down [0, 0, -1] "
                "in the standard position (seed 000's table is anchored there)",
            )
        spheres = seg["spheres"]
        if not isinstance(spheres, list):
            raise where.fail("spheres", "must be a list of sphere objects")
        sph = []
        feature_seen: set[str] = set()
        for s_k, s in enumerate(spheres):
            sw = Where(shown, f"{where.entry}, spheres[{s_k}]")
            sw.fields(s, {"origin", "radius"}, {"features"})
            feats = []
            if not isinstance(s.get("features", []), list):
                raise sw.fail("features", "must be a list of {name, direction} objects")
            for f_k, f in enumerate(s.get("features", [])):
                fw = Where(shown, f"{sw.entry}, features[{f_k}]")
                fw.fields(f, FEATURE_FIELDS)
                fname = fw.string(f, "name")
                if fname in feature_seen or "." in fname:
                    raise fw.fail(
                        "name",
                        f"feature names must be unique within a segment and "
                        f"contain no '.', got {fname!r}",
                    )
                feature_seen.add(fname)
                feats.append((fname, fw.vector(f, "direction", unit=True)))
            sph.append(
                (
                    sw.vector(s, "origin", bound=POSITION_M),
                    sw.number(s, "radius", within=LENGTH_M, unit="m"),
                    feats,
                )
            )
        parsed.append(
            dict(
                name=nm,
                proximal=prox,
                distal=dist,
                std=std,
                direction=direction,
                spheres=sph,
                length=where.number(seg, "length", within=LENGTH_M, unit="m"),
                mass=where.number(seg, "mass", within=MASS_KG, unit="kg"),
                centroid=where.vector(seg, "centroid", bound=POSITION_M),
                limits=_limits(where, seg),
            )
        )

    # The tree: each segment's parent ends at its proximal joint.
    if root_name not in {p["proximal"] for p in parsed}:
        raise top.fail("root_joint", f"no segment starts at the root joint {root_name!r}")
    for k, p in enumerate(parsed):
        if p["proximal"] != root_name and p["proximal"] not in by_distal:
            raise Where(shown, f"segment {p['name']!r} (segments[{k}])").fail(
                "proximal",
                f"unknown joint {p['proximal']!r}: it is neither the root joint {root_name!r} "
                "nor the distal joint of any segment",
            )
    order: list[int] = []
    depth = {}
    queue = deque([(k, 1) for k, p in enumerate(parsed) if p["proximal"] == root_name])
    while queue:
        k, d = queue.popleft()
        order.append(k)
        depth[k] = d
        queue.extend(
            (c, d + 1) for c, p in enumerate(parsed) if p["proximal"] == parsed[k]["distal"]
        )
    if len(order) < len(parsed):
        k = next(k for k in range(len(parsed)) if k not in depth)
        cycle, seen = [parsed[k]["name"]], {k}
        while True:
            k = by_distal[parsed[k]["proximal"]]
            cycle.append(parsed[k]["name"])
            if k in seen:
                break
            seen.add(k)
        raise Where(shown, f"segment {cycle[0]!r}").fail(
            "proximal",
            f"cycle in the tree: {' -> '.join(cycle)}; it never reaches the root "
            f"joint {root_name!r}",
        )
    body = _build(name, shown, root_name, [parsed[k] for k in order], [depth[k] for k in order])
    if "spine" in doc:
        spine_path = path.parent / top.string(doc, "spine")
        if not spine_path.is_file():
            raise top.fail("spine", f"no spine file at {str(spine_path)!r} (relative to the body)")
        spine = load_spine(spine_path)
        for joint, seg in zip(spine.joint_names, spine.segment_names):
            if seg not in body.segment_names:
                raise top.fail(
                    "spine",
                    f"{spine_path}: joint {joint!r} moves segment {seg!r}, which the "
                    "body does not have",
                )
        body = dataclasses.replace(body, spine=spine)
    return body


def _build(name: str, source: str, root_name: str, segs: list[dict], depths: list[int]) -> Body:
    """Arrays and static structure from parsed segments in breadth-first order."""
    names = (WHOLE_BODY,) + tuple(s["name"] for s in segs)
    joints = (CENTER_OF_GRAVITY, root_name) + tuple(s["distal"] for s in segs)
    seg_of_distal = {s["distal"]: i + 1 for i, s in enumerate(segs)}
    seg_of_distal[root_name] = 0
    parent = (-1,) + tuple(seg_of_distal[s["proximal"]] for s in segs)
    n = len(names)

    R_rest = np.zeros((n, 3, 3))
    R_rest[0] = np.eye(3)
    for i, s in enumerate(segs, start=1):
        R_rest[i] = cross_of_axes(s["direction"])
    # In the standard position every socket frame is the world frame, so the socket turn is
    # the inverse of the parent's (untwisted) standard frame.
    R_parent_socket = np.stack([np.eye(3) if p < 0 else R_rest[p].T for p in parent])

    lim = [("free", [-math.pi] * 2, [math.pi] * 2, math.pi, -math.inf, math.inf)]
    lim += [s["limits"] for s in segs]
    big = 1e6  # "free" twist: no bound, kept finite so arithmetic stays finite
    sphere_segment, origins, radii, feature_names, feature_sphere, feature_dirs = (
        [],
        [],
        [],
        [],
        [],
        [],
    )
    enclosure = [(0.0, 0.0)]
    for i, s in enumerate(segs, start=1):
        first = len(radii)
        for origin, radius, feats in s["spheres"]:
            for fname, fdir in feats:
                feature_names.append(f"{s['name']}.{fname}")
                feature_sphere.append(len(radii))
                feature_dirs.append(fdir)
            sphere_segment.append(i)
            origins.append(origin)
            radii.append(radius)
        enclosure.append(
            _enclosure(np.asarray(origins[first:]).reshape(-1, 3), np.asarray(radii[first:]))
        )

    levels: dict[int, list[int]] = {}
    for i, d in enumerate(depths, start=1):
        levels.setdefault(d, []).append(i)

    body = Body(
        name=name,
        source=source,
        segment_names=names,
        joint_names=joints,
        parent=parent,
        proximal_joint=(0,) + tuple(joints.index(s["proximal"]) for s in segs),
        distal_joint=tuple(range(1, n + 1)),
        levels=((0,),) + tuple(tuple(levels[d]) for d in sorted(levels)),
        standard_kind=("swing",) + tuple(s["std"] for s in segs),
        limit_kind=tuple(x[0] for x in lim),
        sphere_segment=tuple(sphere_segment),
        feature_names=tuple(feature_names),
        feature_sphere=tuple(feature_sphere),
        root_joint=1,
        default_root_joint=1,
        lengths=device_array([0.0] + [s["length"] for s in segs]),
        R_parent_socket=device_array(R_parent_socket),
        R_socket_rest=device_array(R_rest),
        swing_lo=device_array([x[1] for x in lim]),
        swing_hi=device_array([x[2] for x in lim]),
        swing_max=device_array([x[3] for x in lim]),
        twist_lo=device_array([max(x[4], -big) for x in lim]),
        twist_hi=device_array([min(x[5], big) for x in lim]),
        masses=device_array([0.0] + [s["mass"] for s in segs]),
        centroids=device_array(np.stack([np.zeros(3)] + [s["centroid"] for s in segs])),
        sphere_origins=device_array(np.asarray(origins).reshape(-1, 3)),
        sphere_radii=device_array(np.asarray(radii)),
        feature_directions=device_array(np.asarray(feature_dirs).reshape(-1, 3)),
        enclosure_z=device_array([e[0] for e in enclosure]),
        enclosure_radii=device_array([e[1] for e in enclosure]),
        rest_position=device_array(np.zeros(3)),
        R_world_pin_rest=device_array(np.eye(3)),
    )
    return _stand_on_ground(body)


def _stand_on_ground(body: Body) -> Body:
    """Place the standard position so the lowest sphere touches z = 0 with the root joint
    above the world origin."""
    _, centers = rest_geometry(body)
    radii = np.asarray(body.sphere_radii)
    lowest = float(np.min(centers[:, 2] - radii)) if body.n_spheres else 0.0
    return eqx.tree_at(lambda b: b.rest_position, body, device_array([0.0, 0.0, -lowest]))
