"""Loading and validating body files and spine databases (both schemas, with the physical
ranges, in data/SCHEMA.md).

Every error is a `BodyFileError` naming the file, the entry, the field and what is
expected, e.g. ``body.json: segment 'left_forearm' (segments[12]), field 'length': must lie
in [0.0001, 10] m, got -0.2``. A file that cannot be read (missing aside) or is not UTF-8
JSON is a `BodyFileError` naming the file too.
"""

import dataclasses
import json
import math
from collections import deque
from importlib import resources
from pathlib import Path
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._body import CENTER_OF_GRAVITY, WHOLE_BODY, Body, Spine, rest_geometry
from ._orientation import LIMBS
from ._rotations import cross_of_axes

SCHEMA = "diffbody.body/1"
TOP_FIELDS = {"schema", "name", "description", "sources", "root_joint", "segments", "spine"}
FEATURE_FIELDS = {"name", "direction"}
LIMIT_FIELDS = {
    "box": {"swing_x_deg", "swing_y_deg", "twist_deg"},
    "cone": {"swing_max_deg", "twist_deg"},
    "hinge": {"swing_y_deg", "twist_deg"},
    "free": set(),
}
OPTIONAL_LIMIT_FIELDS = {"box": {"swing_max_deg"}}
DEFAULT_SWING_MAX_DEG = 179.0
SPINE_SCHEMA = "diffbody.spine/1"
SPINE_ROTATIONS = ("flexion", "axial", "lateral")  # columns of the spine's angle arrays
SPINE_TOP_FIELDS = {"schema", "joints", "vertebrae"}
SPINE_OPTIONAL_FIELDS = {"sources", "angles", "description", "initiator"}
SPINE_JOINT_FIELDS = {
    "name",
    "segment",
    "rest_deg",
    "limits_deg",
    "disc_height_mm",
    "flexion_axis_offset_mm",
}
DEFAULT_SPINE_INITIATOR = "T12_L1"  # the thoracolumbar junction (seed 004's examples)

# Physical ranges (SCHEMA.md): a value outside is a typo or a unit slip (mm for m), and
# float32 kinematics stays finite and well-scaled inside them.
LENGTH_M = (1e-4, 10.0)  # segment lengths and sphere radii
MASS_KG = (0.0, 1000.0)  # massless segments stay legal
POSITION_M = 10.0  # |coordinate| of centroids and sphere origins in the cross of axes
SPINE_ANGLE_DEG = 90.0  # |rest and limit angles| of one intervertebral joint
DISC_HEIGHT_MM = (0.0, 50.0)
AXIS_OFFSET_MM = 100.0  # |flexion-axis offset| from the disc centre
VERTEBRA_SIZE_MM = (1.0, 200.0)
MIN_SWING_MAX_DEG = 1e-3


class _Object(dict):
    """A JSON object that remembers the keys it was given twice (json keeps the last)."""

    duplicates: tuple[str, ...] = ()


def _object(pairs: list[tuple[str, Any]]) -> _Object:
    obj = _Object(pairs)
    keys = [k for k, _ in pairs]
    obj.duplicates = tuple(sorted({k for k in keys if keys.count(k) > 1}))
    return obj


class BodyFileError(ValueError):
    """A body file that cannot be loaded; the message says where and how to fix it."""


class _Where:
    """Where we are in the file, for error messages."""

    def __init__(self, path: str, entry: str):
        self.path, self.entry = path, entry

    def fail(self, field: str | None, message: str) -> BodyFileError:
        at = f", field {field!r}" if field else ""
        return BodyFileError(f"{self.path}: {self.entry}{at}: {message}")

    def fields(self, obj: Any, required: set[str], optional: set[str] = frozenset()) -> None:
        """obj is an object with every required field, no unknown one, none given twice; the
        free-text fields `source` and `description`, where allowed and given, are text."""
        if not isinstance(obj, dict):
            raise self.fail(None, f"must be a JSON object, got {type(obj).__name__}")
        for f in getattr(obj, "duplicates", ()):
            raise self.fail(f, "given twice; keep one")
        for f in sorted(required - obj.keys()):
            raise self.fail(f, "missing (required)")
        for f in sorted(obj.keys() - required - optional):
            allowed = ", ".join(sorted(required | optional))
            raise self.fail(f, f"unknown field; allowed fields are: {allowed}")
        for f in ("source", "description"):
            if f in obj:
                self.string(obj, f)

    def string(self, obj: dict, field: str) -> str:
        v = obj[field]
        if not isinstance(v, str) or not v:
            raise self.fail(field, f"must be a non-empty string, got {v!r}")
        return v

    def number(
        self,
        obj: dict,
        field: str,
        *,
        positive=False,
        within: tuple[float, float] | None = None,
        unit: str = "",
    ) -> float:
        """A finite number; > 0 when `positive`; in [lo, hi] `unit` when `within` is given."""
        v = _finite(self, field, obj[field])
        if positive and v <= 0:
            raise self.fail(field, f"must be > 0, got {v}")
        if within is not None:
            _bounded(self, field, v, within, unit)
        return v

    def numbers(self, obj: dict, field: str, n: int, what: str) -> list[float]:
        """A list of n finite numbers (`what` names them, e.g. "[x, y, z]")."""
        v = obj[field]
        if not isinstance(v, list) or len(v) != n:
            raise self.fail(field, f"must be a list of {n} numbers {what}, got {v!r}")
        return [_finite(self, field, x) for x in v]

    def vector(
        self, obj: dict, field: str, *, unit=False, bound: float | None = None
    ) -> np.ndarray:
        """[x, y, z]: finite, each |coordinate| <= bound; `unit` normalises a direction."""
        a = np.asarray(self.numbers(obj, field, 3, "[x, y, z]"))
        if bound is not None and np.max(np.abs(a)) > bound:
            raise self.fail(
                field, f"every coordinate must lie in [-{bound:g}, {bound:g}] m, got {a.tolist()}"
            )
        if unit:
            scaled = a / max(np.max(np.abs(a)), 1e-300)  # |a| of 1e300 must not overflow
            if np.max(np.abs(a)) < 1e-9:
                raise self.fail(field, f"must be a non-zero direction, got {a.tolist()}")
            a = scaled / np.linalg.norm(scaled)
        return a

    def range_deg(self, obj: dict, field: str, bound: float = 180.0) -> tuple[float, float]:
        """[lo, hi] in degrees within [-bound, bound], returned in radians."""
        lo, hi = self.numbers(obj, field, 2, "[lo, hi] in degrees")
        if lo > hi:
            raise self.fail(field, f"inverted limits: lo {lo} > hi {hi}; expected lo <= hi")
        if lo < -bound or hi > bound:
            raise self.fail(
                field, f"must lie within [-{bound:g}, {bound:g}] degrees, got {[lo, hi]}"
            )
        return math.radians(lo), math.radians(hi)


def _finite(where: _Where, field: str, v: Any) -> float:
    """A JSON number as a finite float (not a bool, not a string, not 1e400 or NaN)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise where.fail(field, f"must be a number, got {type(v).__name__} {v!r}")
    try:
        x = float(v)  # an integer too large for a float raises OverflowError
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        shown = v if isinstance(v, float) else f"an integer of {len(str(v))} digits"
        raise where.fail(field, f"must be a finite number, got {shown}")
    return x


def _limits(where: _Where, seg: dict) -> tuple[str, list[float], list[float], float, float, float]:
    """Parse a segment's limits into (kind, swing_lo, swing_hi, swing_max, twist_lo, twist_hi)."""
    lim = seg["limits"]
    w = _Where(where.path, where.entry + ", limits")
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


def data_file(name: str) -> Path:
    """A file of the embedded data: data/ of a source checkout or of the installed wheel."""
    for folder in (
        Path(__file__).resolve().parent.parent / "data",  # a source checkout
        Path(str(resources.files("diffbody"))) / "data",  # an installed wheel
    ):
        if (folder / name).is_file():
            return folder / name
    raise FileNotFoundError(f"diffbody: embedded data file {name!r} not found")


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


def _read_json(path: Path, kind: str) -> Any:
    """The JSON document of a `kind` ("body" or "spine") file; every failure names the file.
    Objects keep the keys given twice (`_Object.duplicates`) for `_Where.fields` to reject."""
    shown = str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"{shown}: no such {kind} file") from None
    except IsADirectoryError:
        raise BodyFileError(f"{shown}: is a directory; expected a {kind} JSON file") from None
    except UnicodeDecodeError as e:
        raise BodyFileError(
            f"{shown}: not UTF-8 text (byte 0x{e.object[e.start]:02x} at offset {e.start}); "
            f"a {kind} file is JSON saved as UTF-8"
        ) from None
    except OSError as e:
        raise BodyFileError(f"{shown}: cannot read the {kind} file: {e.strerror}") from None
    try:
        return json.loads(text, object_pairs_hook=_object)
    except json.JSONDecodeError as e:
        raise BodyFileError(
            f"{shown}: not valid JSON: {e.msg} at line {e.lineno} column {e.colno}"
        ) from None
    except RecursionError:
        raise BodyFileError(f"{shown}: not valid JSON: nested too deeply") from None


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
    doc = _read_json(path, "body")
    top = _Where(shown, "top level")
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
        where = _Where(shown, f"segment {label!r} (segments[{k}])" if label else f"segments[{k}]")
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
            sw = _Where(shown, f"{where.entry}, spheres[{s_k}]")
            sw.fields(s, {"origin", "radius"}, {"features"})
            feats = []
            if not isinstance(s.get("features", []), list):
                raise sw.fail("features", "must be a list of {name, direction} objects")
            for f_k, f in enumerate(s.get("features", [])):
                fw = _Where(shown, f"{sw.entry}, features[{f_k}]")
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
            raise _Where(shown, f"segment {p['name']!r} (segments[{k}])").fail(
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
        raise _Where(shown, f"segment {cycle[0]!r}").fail(
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
        lengths=jnp.asarray([0.0] + [s["length"] for s in segs]),
        R_parent_socket=jnp.asarray(R_parent_socket),
        R_socket_rest=jnp.asarray(R_rest),
        swing_lo=jnp.asarray([x[1] for x in lim]),
        swing_hi=jnp.asarray([x[2] for x in lim]),
        swing_max=jnp.asarray([x[3] for x in lim]),
        twist_lo=jnp.asarray([max(x[4], -big) for x in lim]),
        twist_hi=jnp.asarray([min(x[5], big) for x in lim]),
        masses=jnp.asarray([0.0] + [s["mass"] for s in segs]),
        centroids=jnp.asarray(np.stack([np.zeros(3)] + [s["centroid"] for s in segs])),
        sphere_origins=jnp.asarray(np.asarray(origins).reshape(-1, 3)),
        sphere_radii=jnp.asarray(np.asarray(radii)),
        feature_directions=jnp.asarray(np.asarray(feature_dirs).reshape(-1, 3)),
        enclosure_z=jnp.asarray([e[0] for e in enclosure]),
        enclosure_radii=jnp.asarray([e[1] for e in enclosure]),
        rest_position=jnp.zeros(3),
        R_world_pin_rest=jnp.eye(3),
    )
    return _stand_on_ground(body)


def _stand_on_ground(body: Body) -> Body:
    """Place the standard position so the lowest sphere touches z = 0 with the root joint
    above the world origin."""
    _, centers = rest_geometry(body)
    radii = np.asarray(body.sphere_radii)
    lowest = float(np.min(centers[:, 2] - radii)) if body.n_spheres else 0.0
    return eqx.tree_at(lambda b: b.rest_position, body, jnp.asarray([0.0, 0.0, -lowest]))


# --- spine databases ----------------------------------------------------------------------


def load_spine(path: str | Path | None = None) -> Spine:
    """Load and validate a spine database (default: data/spine.json; schema
    "diffbody.spine/1", data/SCHEMA.md).

    Raises:
        BodyFileError: the file is malformed; the message names the file, the joint (or
            vertebra) and the field, and what is expected.
    """
    path = data_file("spine.json") if path is None else Path(path)
    shown = str(path)
    doc = _read_json(path, "spine")
    top = _Where(shown, "top level")
    top.fields(doc, SPINE_TOP_FIELDS, SPINE_OPTIONAL_FIELDS)
    if doc["schema"] != SPINE_SCHEMA:
        raise top.fail("schema", f"must be {SPINE_SCHEMA!r}, got {doc['schema']!r}")
    if "sources" in doc and (
        not isinstance(doc["sources"], list) or not all(isinstance(s, str) for s in doc["sources"])
    ):
        raise top.fail("sources", "must be a list of citation strings")
    if "angles" in doc:
        top.string(doc, "angles")
    joints = doc["joints"]
    if not isinstance(joints, list) or not joints:
        raise top.fail("joints", "must be a non-empty list of joint objects, top to bottom")

    rows = []
    for k, j in enumerate(joints):
        label = j.get("name") if isinstance(j, dict) else None
        where = _Where(shown, f"joint {label!r} (joints[{k}])" if label else f"joints[{k}]")
        where.fields(j, SPINE_JOINT_FIELDS, {"source"})
        name, seg = where.string(j, "name"), where.string(j, "segment")
        for field, value in (("name", name), ("segment", seg)):
            other = [r[field] for r in rows]
            if value in other:
                raise where.fail(
                    field, f"duplicate {field} {value!r} (also joints[{other.index(value)}])"
                )
        if seg == WHOLE_BODY:
            raise where.fail("segment", f"{WHOLE_BODY!r} is not a segment a spine joint moves")
        rest = where.numbers(j, "rest_deg", 3, "(flexion, axial, lateral) in degrees")
        if not isinstance(j["limits_deg"], dict):
            raise where.fail("limits_deg", "must be an object {flexion, axial, lateral: [lo, hi]}")
        lw = _Where(shown, where.entry + ", limits_deg")
        lw.fields(j["limits_deg"], set(SPINE_ROTATIONS))
        lo_hi = [lw.range_deg(j["limits_deg"], r, SPINE_ANGLE_DEG) for r in SPINE_ROTATIONS]
        for axis, rot in enumerate(SPINE_ROTATIONS):
            lo, hi = (math.degrees(x) for x in lo_hi[axis])
            if not lo - 1e-9 <= rest[axis] <= hi + 1e-9:
                raise where.fail(
                    "rest_deg",
                    f"the {rot} rest angle {rest[axis]:g} must lie within limits_deg.{rot} "
                    f"[{lo:g}, {hi:g}]",
                )
        rows.append(
            dict(
                name=name,
                segment=seg,
                rest=np.radians(rest),
                lower=[x[0] for x in lo_hi],
                upper=[x[1] for x in lo_hi],
                disc=where.number(j, "disc_height_mm", within=DISC_HEIGHT_MM, unit="mm"),
                offset=[
                    _bounded(where, "flexion_axis_offset_mm", x, AXIS_OFFSET_MM, "mm")
                    for x in where.numbers(j, "flexion_axis_offset_mm", 2, "[x, z] in mm")
                ],
            )
        )
    names = tuple(r["name"] for r in rows)
    initiator = doc.get("initiator", DEFAULT_SPINE_INITIATOR)
    if "initiator" in doc:
        top.string(doc, "initiator")
    if initiator not in names:
        raise top.fail(
            "initiator",
            f"no joint {initiator!r}: name the joint where a bend begins by default, one of "
            f"{list(names)}" + ("" if "initiator" in doc else " (the default is T12_L1)"),
        )

    verts = doc["vertebrae"]
    # The top joint (C7-T1) moves the neck; every joint below it moves a vertebra.
    expected = [r["segment"] for r in rows[1:]]
    if not isinstance(verts, list):
        raise top.fail("vertebrae", "must be a list of vertebra objects")
    sizes = []
    for k, v in enumerate(verts):
        label = v.get("name") if isinstance(v, dict) else None
        vw = _Where(shown, f"vertebra {label!r} (vertebrae[{k}])" if label else f"vertebrae[{k}]")
        vw.fields(v, {"name", "size_mm"}, {"source"})
        vname = vw.string(v, "name")
        if k >= len(expected) or vname != expected[k]:
            raise vw.fail(
                "name",
                f"expected {expected[k]!r}, the segment of joints[{k + 1}]"
                if k < len(expected)
                else f"one vertebra per joint below the top one: {len(expected)} expected",
            )
        size = vw.numbers(v, "size_mm", 3, "[depth, breadth, height] in mm")
        for x in size:
            _bounded(vw, "size_mm", x, VERTEBRA_SIZE_MM, "mm")
        sizes.append(size)
    if len(verts) < len(expected):
        raise top.fail(
            "vertebrae",
            f"missing {expected[len(verts) :]}: one vertebra per joint below the top one, "
            "in the joints' order",
        )

    return Spine(
        joint_names=names,
        initiator=names.index(initiator),
        segment_names=tuple(r["segment"] for r in rows),
        vertebra_names=tuple(expected),
        rest=jnp.asarray(np.stack([r["rest"] for r in rows])),
        lower=jnp.asarray([r["lower"] for r in rows]),
        upper=jnp.asarray([r["upper"] for r in rows]),
        disc_heights=jnp.asarray([r["disc"] for r in rows]) / 1000.0,
        flexion_axis_offsets=jnp.asarray([r["offset"] for r in rows]) / 1000.0,
        vertebra_sizes=jnp.asarray(np.reshape(sizes, (-1, 3))) / 1000.0,
    )


def _bounded(where: _Where, field: str, x: float, bound, unit: str = "") -> float:
    """x within bound, (lo, hi) or b for [-b, b], in `unit`; else a BodyFileError."""
    lo, hi = bound if isinstance(bound, tuple) else (-bound, bound)
    if not lo <= x <= hi:
        unit = f" {unit}" if unit else ""
        raise where.fail(field, f"must lie in [{lo:g}, {hi:g}]{unit}, got {x:g}")
    return x


# --- writing ----------------------------------------------------------------------------------


def _deg(x) -> float:
    return float(np.degrees(float(x)))


def _limits_doc(body: Body, i: int) -> dict:
    """The stop function of segment i as a body file's `limits` object (degrees)."""
    kind = body.limit_kind[i]
    if kind == "free":
        return {"kind": "free"}
    lo, hi = np.asarray(body.swing_lo[i]), np.asarray(body.swing_hi[i])
    twist = [_deg(body.twist_lo[i]), _deg(body.twist_hi[i])]
    smax = _deg(body.swing_max[i])
    if kind == "cone":
        return {"kind": "cone", "swing_max_deg": smax, "twist_deg": twist}
    doc = {"kind": kind}
    if kind == "box":
        doc["swing_x_deg"] = [_deg(lo[0]), _deg(hi[0])]
    doc["swing_y_deg"] = [_deg(lo[1]), _deg(hi[1])]
    if kind == "box" and abs(smax - DEFAULT_SWING_MAX_DEG) > 1e-9:
        doc["swing_max_deg"] = smax
    doc["twist_deg"] = twist
    return doc


def body_document(body: Body, spine_file: str | None = None) -> dict:
    """The body as a `diffbody.body/1` document (data/SCHEMA.md); `spine_file` names its
    spine database relative to the body file."""
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
