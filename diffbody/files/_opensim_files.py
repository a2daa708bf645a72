"""OpenSim's set-up files, so that an OpenSim IK set-up can be reused: the IK task set
(`read_ik_tasks`: {marker: weight}, what `fit_motion`'s `weights` takes) and the marker set
of a marker-set file or a model (`load_opensim_markerset`: a `MarkerSet` on diffbody's
segments).

An OpenSim marker sits at a `location` (m) in its body's frame. Every body frame of OpenSim's
gait models is parallel to the ground's in the default pose (all coordinates 0: standing,
arms hanging): x forward, y up, z to the right. diffbody's standard position has x forward,
y to the body's left, z up. A marker of OpenSim body b is carried to our segment s by

    d = R_std_osim @ (location - q_b)        standard axes, from s's proximal joint
    d += (k_b - 1) (d . a_s) a_s             axial scale along s's axis a_s

with q_b the point of b's frame at our segment's proximal joint and k_b = (our length) /
(OpenSim's length) (`OPENSIM_BODIES`), then resolved as a `diffbody.markerset/1` "offset" in
"standard" axes (`_markerset.resolve_offset`).
"""

import dataclasses
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from .._body import Body, rest_geometry
from ._data_files import read_text
from ._marker_trial import LAB_AXES, MarkerFileError
from ._markerset_file import (
    DEFAULT_MARKER_RADIUS,
    MarkerEntry,
    MarkerSet,
    built_markerset,
    resolve_offset,
)

# An OpenSim body frame in the default pose has the axes of OpenSim's lab (x forward, y up,
# z right): d_std = R_STD_OSIM @ d_osim.
R_STD_OSIM = LAB_AXES["opensim"]
# `<fixed>true` markers are kept in place by OpenSim's marker placer: bony landmarks, as
# opensim-gait.json's anatomical 5 mm ones; the others move, as its shoe markers' 20 mm.
FIXED = ("anatomical", 0.005)
FREE = ("tracking", 0.02)


@dataclasses.dataclass(frozen=True)
class OpenSimBody:
    """How one OpenSim body's markers go onto diffbody's segments."""

    segments: tuple[str, ...]  # our candidate segments; several: the nearest one per marker
    proximal: tuple[float, float, float]  # m, body frame: the point at our proximal joint
    length: float | None  # m, OpenSim's span of our `span`; None: no axial scale
    span: tuple[str, str]  # our length: the first's proximal to the second's distal joint


def _side(right: dict[str, OpenSimBody]) -> dict[str, OpenSimBody]:
    """The right bodies and their left mirror images (z -> -z, right_ -> left_)."""
    out = {}
    for name, b in right.items():
        out[name] = b
        out[name[:-2] + "_l"] = OpenSimBody(
            tuple(s.replace("right_", "left_") for s in b.segments),
            (b.proximal[0], b.proximal[1], -b.proximal[2]),
            b.length,
            tuple(s.replace("right_", "left_") for s in b.span),
        )
    return out


# Knee centre in femur_r at knee angle 0 (gait2354's knee_r translation splines there).
_KNEE = (-0.0045, -0.3958, 0.0)
# Ankle centre (talus_r origin) in calcn_r: minus gait2354's subtalar_r location in talus_r.
_ANKLE_IN_CALCN = (0.04877, 0.04195, -0.00792)
# The bodies of OpenSim's gait models (gait2354, gait2392, Rajagopal 2016) and our segments.
# Lower body and torso: the joint locations of the generic gait2354_simbody.osim
# (data/mocap). gait2354 has no arms: those are Rajagopal et al. 2016's generic model's
# (the arm of Hamner et al. 2010). gait2354's foot and torso end in no joint: their span runs
# to the generic R.Toe.Tip and Top.Head markers (gait2354_Scale_MarkerSet.xml).
OPENSIM_BODIES: dict[str, OpenSimBody] = {
    # Hip joints' midpoint: hip_r at (-0.0707, -0.0661, +-0.0835); to back at
    # (-0.1007, 0.0815, 0), our pelvis's distal joint (the lumbosacral).
    "pelvis": OpenSimBody(("pelvis",), (-0.0707, -0.0661, 0.0), 0.1506, ("pelvis", "pelvis")),
    **_side(
        {
            "femur_r": OpenSimBody(
                ("right_thigh",), (0.0, 0.0, 0.0), 0.3958, ("right_thigh", "right_thigh")
            ),
            # The patella rides on the femur: placed as if its origin were the knee centre
            # (Rajagopal's patella origin lies a few cm in front of it at full extension).
            "patella_r": OpenSimBody(
                ("right_thigh",),
                (-_KNEE[0], -_KNEE[1], 0.0),
                0.3958,
                ("right_thigh", "right_thigh"),
            ),
            # Knee centre = tibia origin; ankle_r at (0, -0.43, 0).
            "tibia_r": OpenSimBody(
                ("right_shank",), (0.0, 0.0, 0.0), 0.43, ("right_shank", "right_shank")
            ),
            # Ankle to the toe tip, forward: calcn_r's R.Toe.Tip x 0.26 - 0.04877.
            "talus_r": OpenSimBody(
                ("right_foot",), (0.0, 0.0, 0.0), 0.2112, ("right_foot", "right_foot")
            ),
            "calcn_r": OpenSimBody(
                ("right_foot",), _ANKLE_IN_CALCN, 0.2112, ("right_foot", "right_foot")
            ),
            # mtp_r at (0.1788, -0.002, 0.00108) in calcn_r.
            "toes_r": OpenSimBody(
                ("right_foot",),
                (0.04877 - 0.1788, 0.04195 + 0.002, -0.00792 - 0.00108),
                0.2112,
                ("right_foot", "right_foot"),
            ),
            # Shoulder centre = humerus origin; elbow_r at (0.013144, -0.286273, -0.009595).
            "humerus_r": OpenSimBody(
                ("right_upper_arm",),
                (0.0, 0.0, 0.0),
                0.2866,
                ("right_upper_arm", "right_upper_arm"),
            ),
            # Elbow centre = ulna origin; radius_hand_r (wrist) at (-0.008797, -0.235841,
            # 0.01361) in radius_r, whose origin is radioulnar_r's (-0.006727, -0.013007,
            # 0.026083) in ulna_r.
            "ulna_r": OpenSimBody(
                ("right_forearm",), (0.0, 0.0, 0.0), 0.2525, ("right_forearm", "right_forearm")
            ),
            "radius_r": OpenSimBody(
                ("right_forearm",),
                (0.006727, 0.013007, -0.026083),
                0.2525,
                ("right_forearm", "right_forearm"),
            ),
            # Wrist centre = hand origin; the hand ends in no joint: unscaled.
            "hand_r": OpenSimBody(
                ("right_hand",), (0.0, 0.0, 0.0), None, ("right_hand", "right_hand")
            ),
        }
    ),
    # Back joint = torso origin = our lumbosacral joint; to the vertex (Top.Head, y 0.657).
    # The torso carries the thorax, the shoulders and the head: each marker goes to the
    # nearest of these segments, as opensim-gait.json places the sternum, the acromia and
    # the top of the head.
    "torso": OpenSimBody(
        ("T6", "right_clavicle", "left_clavicle", "head"), (0.0, 0.0, 0.0), 0.657, ("L5", "head")
    ),
}


# --- XML ---------------------------------------------------------------------------------
def _parse(path, what: str) -> tuple[str, ET.Element]:
    """(the path as shown, the root element); a missing file or bad XML is a
    `MarkerFileError` naming the file and the line."""
    shown = str(path)
    text = read_text(path, f"OpenSim {what}", MarkerFileError, f"an OpenSim {what} is XML")
    try:
        return shown, ET.fromstring(text)
    except ET.ParseError as e:
        line, col = e.position
        raise MarkerFileError(
            f"{shown}: line {line}, column {col + 1}: not XML ({e.msg.split(':')[0]}); an "
            f"OpenSim {what} is an XML document, check the tags around that line"
        ) from None


def _one(shown: str, root: ET.Element, tag: str, what: str) -> ET.Element:
    """The one `<tag>` anywhere in the document (the root itself included)."""
    found = list(root.iter(tag))
    if not found:
        raise MarkerFileError(
            f"{shown}: no <{tag}> in the document (root <{root.tag}>); give an OpenSim {what}"
        )
    if len(found) > 1:
        names = ", ".join(repr(e.get("name", "")) for e in found)
        raise MarkerFileError(
            f"{shown}: {len(found)} <{tag}>s ({names}); give a file that holds one"
        )
    return found[0]


def _text(el: ET.Element, tag: str) -> str | None:
    child = el.find(tag)
    return None if child is None or child.text is None else child.text.strip()


def _named_objects(
    shown: str, owner: ET.Element, tag: str, kind: str
) -> list[tuple[str, ET.Element]]:
    """(name, element) of each `<tag>` under `owner`'s `<objects>`: a missing, empty or
    repeated name is an error naming the entry."""
    out: list[tuple[str, ET.Element]] = []
    for k, el in enumerate(owner.iterfind(f"objects/{tag}")):
        name = (el.get("name") or "").strip()
        if not name:
            raise MarkerFileError(
                f"{shown}: {kind} {k} (<{tag}> number {k + 1}), field 'name': missing; write "
                f'<{tag} name="..."> with the marker\'s label in the trial files'
            )
        if any(name == n for n, _ in out):
            raise MarkerFileError(f"{shown}: {kind} {name!r}, field 'name': given twice; keep one")
        out.append((name, el))
    return out


# --- IK tasks ----------------------------------------------------------------------------
def read_ik_tasks(path) -> dict[str, float]:
    """{marker name: weight} of an OpenSim IK task set, for `fit_motion(..., weights=...)`.

    Args:
        path: a task-set file (`<OpenSimDocument>` holding an `<IKTaskSet>`) or a set-up
            file holding one anywhere (an IK tool's, e.g. data/mocap/subject01_Setup_IK.xml;
            an `<IKTaskSet file="...">` is read from that file, relative to the set-up's).

    Every `<IKMarkerTask>` whose `<apply>` is "true" (any case; OpenSim's default when it is
    absent) gives its `<weight>` (default 1). Tasks applied false are left out: `fit_motion`
    gives the markers a mapping does not name weight 0, as OpenSim does. `<IKCoordinateTask>`s
    are ignored: diffbody's posture has no OpenSim coordinates to hold.

    A missing file is a FileNotFoundError; every other error is a `MarkerFileError` naming the
    file, the task and the field: not XML (with the line), no `<IKTaskSet>`, a task without a
    name, a weight that is not a finite number >= 0.
    """
    shown, root = _parse(path, "IK set-up or task set")
    tasks = _one(shown, root, "IKTaskSet", "IK task set or IK set-up file")
    if tasks.get("file") and tasks.find("objects") is None:
        # A set-up may name its task set's file instead of holding it.
        return read_ik_tasks(Path(path).parent / tasks.get("file").strip())
    out = {}
    for name, el in _named_objects(shown, tasks, "IKMarkerTask", "IK marker task"):
        weight = _text(el, "weight")
        try:
            w = 1.0 if weight is None else float(weight)
        except ValueError:
            w = math.nan
        if not (math.isfinite(w) and w >= 0):
            raise MarkerFileError(
                f"{shown}: IK marker task {name!r}, field 'weight': must be a finite number "
                f">= 0, got {weight!r}; write e.g. <weight>1</weight>"
            )
        if (_text(el, "apply") or "true").lower() == "true":
            out[name] = w
    return out


# --- marker sets ---------------------------------------------------------------------------
def _body_name(el: ET.Element) -> str | None:
    """The body a marker is on: OpenSim 3's `<body>` or the last part of OpenSim 4's
    `<socket_parent_frame>` path (/bodyset/femur_r)."""
    body = _text(el, "body")
    if body is None:
        frame = _text(el, "socket_parent_frame")
        body = None if frame is None else frame.rstrip("/").rsplit("/", 1)[-1]
    return body or None


def _bone_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance from p to the line segment a-b."""
    ab = b - a
    t = np.clip((p - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t * ab)))


def _location(where: MarkerEntry, el: ET.Element, osim_body: str | None) -> np.ndarray:
    """A marker's `<location>`: three finite numbers (m, in its body's frame)."""
    try:
        location = np.array([float(v) for v in (_text(el, "location") or "").split()])
    except ValueError:
        location = np.array([math.nan])
    if location.shape != (3,) or not np.all(np.isfinite(location)):
        raise where.fail(
            "location",
            f"must be three finite numbers (m, in body {osim_body!r}'s frame), got "
            f"{_text(el, 'location')!r}",
        )
    return location


def _markers_of(path) -> tuple[str, ET.Element, list[tuple[str, ET.Element]]]:
    """The file as shown, its `<MarkerSet>` and that set's markers (at least one)."""
    shown, root = _parse(path, "marker set (.xml) or model (.osim)")
    markerset = _one(shown, root, "MarkerSet", "marker set (.xml) or model (.osim)")
    markers = _named_objects(shown, markerset, "Marker", "marker")
    if not markers:
        raise MarkerFileError(
            f"{shown}: <MarkerSet name={markerset.get('name', '')!r}> holds no <Marker>; give "
            "a marker set with its markers (a generic model often has none: use its marker "
            "set file)"
        )
    return shown, markerset, markers


def read_model_markers(path) -> dict[str, tuple[str, np.ndarray]]:
    """{marker: (its OpenSim body, its location (3,) m in that body's frame)} of a marker-set
    `.xml` or a model's `<MarkerSet>`: where the model's markers sit on its bones, which
    locates the model's body frames on ours (`diffbody.mocap.model_frames`). Errors are
    `MarkerFileError`s naming the file, the marker and the field."""
    shown, _, markers = _markers_of(path)
    out = {}
    for name, el in markers:
        osim_body = _body_name(el)
        out[name] = (osim_body, _location(MarkerEntry(shown, f"marker {name!r}"), el, osim_body))
    return out


def load_opensim_markerset(path, body: Body) -> MarkerSet:
    """An OpenSim marker set resolved for `body`: a marker-set `.xml` (e.g.
    data/mocap/gait2354_Scale_MarkerSet.xml) or the `<MarkerSet>` of an `.osim` model.

    Args:
        path: the file; its document holds one `<MarkerSet>` (OpenSim 3's `<body>` or
            OpenSim 4's `<socket_parent_frame>`; `<location>` in m, in the body's frame).
        body: the body whose segments carry the markers.

    Each marker goes to the segment `OPENSIM_BODIES` gives its OpenSim body, placed as the
    module docstring says; a torso marker to the nearest of the torso's segments (distance
    to their bones in the standard position). `<fixed>true` markers are "anatomical" with
    a 5 mm tolerance, the others "tracking" with 20 mm; every weight is 1 (the IK weights
    are the task set's: `read_ik_tasks`).

    Every error is a `MarkerFileError` naming the file, the marker and the field: a body the
    table lacks (listing those it knows), a body the model has no segment for, a location
    that is not three finite numbers.
    """
    shown, markerset, markers = _markers_of(path)
    rest = rest_geometry(body)  # (joints, sphere centres) of the standard position
    joints = rest[0]
    known = ", ".join(OPENSIM_BODIES)

    def joint(segment: str, end: str) -> np.ndarray:
        seg = body.segment_index(segment)
        return joints[(body.proximal_joint if end == "proximal" else body.distal_joint)[seg]]

    names, segs, kinds, offsets, tolerances = [], [], [], [], []
    for name, el in markers:
        where = MarkerEntry(shown, f"marker {name!r}")
        osim_body = _body_name(el)
        if osim_body not in OPENSIM_BODIES:
            raise where.fail(
                "body",
                f"OpenSim body {osim_body!r} has no diffbody segment; the bodies known are "
                f"{known}; put the marker on one of them",
            )
        table = OPENSIM_BODIES[osim_body]
        missing = [s for s in table.segments + table.span if s not in body.segment_names]
        if missing:
            raise where.fail(
                "body",
                f"OpenSim body {osim_body!r} cannot be placed: body {body.name!r} has no "
                f"segment {', '.join(map(repr, missing))}; the bodies known are {known}",
            )
        location = _location(where, el, osim_body)
        anchor = joint(table.span[0], "proximal")
        d = R_STD_OSIM @ (location - np.asarray(table.proximal))
        if table.length is not None:
            axis = joint(table.span[1], "distal") - anchor
            ours = float(np.linalg.norm(axis))
            axis /= ours
            d = d + (ours / table.length - 1.0) * (d @ axis) * axis
        p = anchor + d  # standard position, world
        segment = min(
            table.segments,
            key=lambda s: _bone_distance(p, joint(s, "proximal"), joint(s, "distal")),
        )
        seg = body.segment_index(segment)
        offset = (p - joint(segment, "proximal")).tolist()
        kind, tolerance = FIXED if (_text(el, "fixed") or "").lower() == "true" else FREE
        names.append(name)
        segs.append(seg)
        kinds.append(kind)
        offsets.append(
            resolve_offset(
                where, {"offset": offset}, body, rest, seg, "standard", DEFAULT_MARKER_RADIUS
            )
        )
        tolerances.append(tolerance)
    name = markerset.get("name") or Path(path).stem
    weights = np.ones(len(names))
    return built_markerset(name, shown, names, segs, kinds, offsets, tolerances, weights, body)
