"""Marker sets (docs/design.md, section 7): which body segment carries each motion-capture marker,
where it sits on it, how far registration may move it and how much it counts in IK.

A marker set file (`data/markersets/<name>.json`, format in data/markersets/README.md)
places markers relative to the body: near a named feature, on the skin of a segment's
spheres, or at a plain offset. `load_markerset` resolves it for one body into a
`MarkerSet`: per-marker offsets in the segment's cross of axes (origin at the proximal
joint, +Z toward the distal joint). A marker turns with its segment's twist by z / length,
exactly like a sphere (seed 000, Fig. 7 as corrected), so its world position is

    p_world = p_proximal[seg] + R_base[seg] @ Rz(tau[seg] * clip(z / length, 0, 1)) @ offset

(`diffbody._kinematics.place_on_segments`).
"""

import math
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import WHOLE_BODY, Body, rest_geometry, unknown_name_error
from .._programs import is_traced
from ._data_files import Where, data_file, read_json
from ._marker_trial import MarkerFileError

SCHEMA = "diffbody.markerset/1"
KINDS = ("anatomical", "tracking")
TOP_FIELDS = {"schema", "name", "markers"}
TOP_OPTIONAL = {"description", "sources", "axes", "marker_radius"}
PLACEMENTS = ("feature", "sphere_surface", "offset")
MARKER_FIELDS = {"name", "segment", "kind", "tolerance", "weight"}
MARKER_OPTIONAL = {"along", "shift", "source", "description"} | set(PLACEMENTS)
AXES = ("segment", "standard")
DEFAULT_MARKER_RADIUS = 0.007  # m, skin to marker centre: a 14 mm marker on its base
TOLERANCE_M = (1e-4, 0.2)  # registration SD; a value outside is a unit slip (mm for m)
WEIGHT = (1e-6, 1e6)
SHIFT_M = 0.2  # |coordinate| of a shift from the feature or skin point
OFFSET_M = 2.0  # |coordinate| of a plain offset


class MarkerSet(eqx.Module):
    """Markers on a body's segments, resolved for one body (`load_markerset`).

    `offsets` are in each segment's cross of axes of the body the set was resolved for;
    `scale_offsets` carries them to a scaled body.
    """

    name: str = eqx.field(static=True)
    source: str = eqx.field(static=True)  # the file it was read from
    names: tuple[str, ...] = eqx.field(static=True)
    segments: tuple[int, ...] = eqx.field(static=True)  # body segment index of each marker
    kinds: tuple[str, ...] = eqx.field(static=True)  # "anatomical" | "tracking"
    offsets: Float[Array, "n 3"]  # m, segment cross of axes
    tolerances: Float[Array, " n"]  # m, prior SD of the registration's move
    weights: Float[Array, " n"]  # IK weight

    @property
    def n_markers(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Position of a marker (KeyError listing the set's markers, closest first)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise unknown_name_error("marker", name, self.names) from None

    def select(self, names) -> "MarkerSet":
        """The set restricted to `names`, in that order."""
        idx = [self.index(n) for n in names]
        return MarkerSet(
            name=self.name,
            source=self.source,
            names=tuple(self.names[i] for i in idx),
            segments=tuple(self.segments[i] for i in idx),
            kinds=tuple(self.kinds[i] for i in idx),
            offsets=_rows(self.offsets, idx),
            tolerances=_rows(self.tolerances, idx),
            weights=_rows(self.weights, idx),
        )


def _rows(a, idx: list[int]):
    """Rows idx of a: a device array's taken on the host and put back (an index of a device
    array compiles a small program per shape), a traced one's in the trace."""
    idx = np.asarray(idx, dtype=int)
    if isinstance(a, np.ndarray) or is_traced(a):
        return a[idx]
    return jax.device_put(np.asarray(a)[idx])


# --- loading -------------------------------------------------------------------------------
class MarkerEntry(Where):
    """Where we are in a marker set file; its failures are `MarkerFileError`s."""

    def fail(self, field: str | None, message: str) -> MarkerFileError:
        at = f", field {field!r}" if field else ""
        return MarkerFileError(f"{self.path}: {self.entry}{at}: {message}")


def markerset_file(name_or_path) -> Path:
    """The file of a shipped set's name ("opensim-gait") or a path to a set file."""
    text = str(name_or_path)
    if isinstance(name_or_path, Path) or text.endswith(".json") or "/" in text or "\\" in text:
        return Path(name_or_path)
    try:
        return data_file(f"markersets/{text}.json")
    except FileNotFoundError:
        folder = data_file("markersets/README.md").parent
        shipped = tuple(sorted(p.stem for p in folder.glob("*.json")))
        raise unknown_name_error("marker set", text, shipped) from None


def _named(where: MarkerEntry, field: str, kind: str, name: Any, valid: tuple[str, ...]) -> int:
    """Index of `name` among `valid`, or an error naming the field with close matches."""
    if not isinstance(name, str) or name not in valid:
        hint = unknown_name_error(kind, str(name), valid).args[0]
        raise where.fail(field, hint + f"; write one of the body's {kind} names")
    return valid.index(name)


def _ray_exit(origins: np.ndarray, radii: np.ndarray, start: np.ndarray, d: np.ndarray) -> float:
    """Distance along the unit ray start + t d to where it leaves the last sphere it
    crosses (the outermost skin); NaN when it crosses none ahead of `start`."""
    rel = start - origins
    b = rel @ d
    disc = b**2 - (np.sum(rel**2, axis=1) - radii**2)
    t = np.where(disc >= 0, -b + np.sqrt(np.maximum(disc, 0.0)), -np.inf)
    best = float(np.max(t)) if len(t) else -np.inf
    return best if best > 0 else math.nan


def resolve_offset(
    where: MarkerEntry, entry: dict, body: Body, rest, seg: int, axes: str, radius: float
):
    """A marker's offset (3,) in its segment's cross of axes, standard position (`rest`:
    the standard position's joints and sphere centres, `rest_geometry`)."""
    R_world_seg = np.asarray(body.R_socket_rest)[seg]  # standard position: socket = world

    def direction(field: str, unit: bool) -> np.ndarray:
        bound = None if unit else SHIFT_M
        v = where.vector(entry, field, unit=unit, bound=bound)
        return R_world_seg.T @ v if axes == "standard" else v

    shift = direction("shift", unit=False) if "shift" in entry else np.zeros(3)
    if "along" in entry and "sphere_surface" not in entry:
        raise where.fail("along", "only a sphere_surface placement takes 'along'; remove it")
    if "feature" in entry:
        f = _named(where, "feature", "feature", entry["feature"], body.feature_names)
        joints, _ = rest
        sph = body.feature_sphere[f]
        f_seg = body.sphere_segment[sph]
        R_f = np.asarray(body.R_socket_rest)[f_seg]
        normal = R_f @ np.asarray(body.feature_directions)[f]
        radius_f = float(np.asarray(body.sphere_radii)[sph])
        local = (
            np.asarray(body.sphere_origins)[sph] + radius_f * np.asarray(body.feature_directions)[f]
        )
        p_world = joints[body.proximal_joint[f_seg]] + R_f @ local + radius * normal
        return R_world_seg.T @ (p_world - joints[body.proximal_joint[seg]]) + shift
    if "sphere_surface" in entry:
        if "along" not in entry:
            raise where.fail(
                "along",
                "missing: a sphere_surface placement needs the fraction of the segment's "
                "length (0 = proximal joint, 1 = distal joint) its ray starts from",
            )
        along = where.number(entry, "along", within=(0.0, 1.0))
        d = direction("sphere_surface", unit=True)
        start = np.array([0.0, 0.0, along * float(np.asarray(body.lengths)[seg])])
        origins, radii = _skin_near(body, rest, seg)
        t = _ray_exit(origins, radii, start, d)
        if math.isnan(t):
            raise where.fail(
                "sphere_surface",
                f"the ray from {along:g} of segment {body.segment_names[seg]!r}'s length "
                f"along {d.round(3).tolist()} (segment axes) meets none of its spheres; turn "
                "it toward the segment's surface, or give a plain 'offset'",
            )
        return start + (t + radius) * d + shift
    offset = where.vector(entry, "offset", bound=OFFSET_M)
    return R_world_seg.T @ offset if axes == "standard" else offset


def _skin_near(body: Body, rest, seg: int) -> tuple[np.ndarray, np.ndarray]:
    """Centres (in segment `seg`'s cross of axes, standard position) and radii of the
    spheres of `seg` and of the segments jointed to it: the skin around a joint is made of
    both sides' spheres (the acromion lies under the upper arm's first sphere)."""
    near = {seg, body.parent[seg]} | {i for i, p in enumerate(body.parent) if p == seg}
    sph = np.flatnonzero(np.isin(np.asarray(body.sphere_segment), sorted(near)))
    joints, centers = rest
    R_world_seg = np.asarray(body.R_socket_rest)[seg]
    local = (centers[sph] - joints[body.proximal_joint[seg]]) @ R_world_seg
    return local, np.asarray(body.sphere_radii)[sph]


def load_markerset(name_or_path, body: Body) -> MarkerSet:
    """Read a marker set file and resolve it for `body` (format: data/markersets/README.md).

    Args:
        name_or_path: a shipped set's name ("opensim-gait") or the path of a set file.
        body: the body whose segments carry the markers.

    Every error is a `MarkerFileError` naming the file, the marker entry, the field and
    the fix (an unknown segment or feature with the closest valid names).
    """
    path = markerset_file(name_or_path)
    shown = str(path)
    doc = read_json(path, "marker set", MarkerFileError)
    top = MarkerEntry(shown, "top level")
    top.fields(doc, TOP_FIELDS, TOP_OPTIONAL)
    if doc["schema"] != SCHEMA:
        raise top.fail("schema", f"expected {SCHEMA!r}, got {doc['schema']!r}")
    name = top.string(doc, "name")
    if "sources" in doc and (
        not isinstance(doc["sources"], list)
        or not all(isinstance(s, str) and s for s in doc["sources"])
    ):
        raise top.fail("sources", "must be a list of non-empty strings (citations)")
    axes = doc.get("axes", "segment")
    if axes not in AXES:
        raise top.fail("axes", f"must be one of {', '.join(AXES)}, got {axes!r}")
    radius = DEFAULT_MARKER_RADIUS
    if "marker_radius" in doc:
        radius = top.number(doc, "marker_radius", within=(0.0, 0.05), unit="m")
    markers = doc["markers"]
    if not isinstance(markers, list) or not markers:
        raise top.fail("markers", "must be a non-empty list of marker entries")
    segments = tuple(s for s in body.segment_names if s != WHOLE_BODY)
    rest = rest_geometry(body)
    names, segs, kinds, offsets, tolerances, weights = [], [], [], [], [], []
    for k, entry in enumerate(markers):
        label = entry.get("name") if isinstance(entry, dict) else None
        where = MarkerEntry(shown, f"marker {label!r} (markers[{k}])" if label else f"markers[{k}]")
        where.fields(entry, MARKER_FIELDS, MARKER_OPTIONAL)
        marker = where.string(entry, "name")
        if marker in names:
            first = names.index(marker)
            raise where.fail("name", f"given twice (also markers[{first}]); rename or drop one")
        seg = body.segment_index(
            segments[_named(where, "segment", "segment", entry["segment"], segments)]
        )
        placed = [p for p in PLACEMENTS if p in entry]
        if len(placed) != 1:
            raise where.fail(
                None,
                f"give exactly one placement of {', '.join(PLACEMENTS)}; found "
                f"{', '.join(placed) or 'none'}",
            )
        if "shift" in entry and placed[0] == "offset":
            raise where.fail("shift", "an 'offset' placement takes no shift; add it to the offset")
        kind = entry["kind"]
        if kind not in KINDS:
            raise where.fail(
                "kind",
                f"must be 'anatomical' (a bony landmark, tight tolerance) or 'tracking' "
                f"(a soft-tissue marker, loose tolerance), got {kind!r}",
            )
        tolerance = where.number(entry, "tolerance", positive=True)
        if not TOLERANCE_M[0] <= tolerance <= TOLERANCE_M[1]:
            raise where.fail(
                "tolerance",
                f"must lie in [{TOLERANCE_M[0]:g}, {TOLERANCE_M[1]:g}] m (the SD of how far "
                f"registration may move the marker), got {tolerance:g}; mm written as m?",
            )
        weight = where.number(entry, "weight", positive=True, within=WEIGHT)
        names.append(marker)
        segs.append(seg)
        kinds.append(kind)
        offsets.append(resolve_offset(where, entry, body, rest, seg, axes, radius))
        tolerances.append(tolerance)
        weights.append(weight)
    return built_markerset(name, shown, names, segs, kinds, offsets, tolerances, weights, body)


def built_markerset(name, source, names, segs, kinds, offsets, tolerances, weights, body):
    """A `MarkerSet` of per-marker lists, its arrays in the body's dtype."""
    dtype = body.lengths.dtype
    return MarkerSet(
        name=name,
        source=source,
        names=tuple(names),
        segments=tuple(segs),
        kinds=tuple(kinds),
        offsets=jnp.asarray(np.array(offsets), dtype),
        tolerances=jnp.asarray(np.array(tolerances), dtype),
        weights=jnp.asarray(np.array(weights), dtype),
    )
