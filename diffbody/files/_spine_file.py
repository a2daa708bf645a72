"""Loading and validating spine databases (schema "diffbody.spine/1", data/SCHEMA.md).

Every error is a `BodyFileError` (`_data_files`) naming the file, the joint (or vertebra),
the field and what is expected.
"""

import math
from pathlib import Path

import numpy as np

from .._body import WHOLE_BODY, Spine
from .._device_arrays import device_array
from ._data_files import Where, bounded, data_file, read_json
from ._schema import (
    AXIS_OFFSET_MM,
    DEFAULT_SPINE_INITIATOR,
    DISC_HEIGHT_MM,
    SPINE_ANGLE_DEG,
    SPINE_JOINT_FIELDS,
    SPINE_OPTIONAL_FIELDS,
    SPINE_ROTATIONS,
    SPINE_SCHEMA,
    SPINE_TOP_FIELDS,
    VERTEBRA_SIZE_MM,
)


def load_spine(path: str | Path | None = None) -> Spine:
    """Load and validate a spine database (default: data/spine.json; schema
    "diffbody.spine/1", data/SCHEMA.md).

    Raises:
        BodyFileError: the file is malformed; the message names the file, the joint (or
            vertebra) and the field, and what is expected.
    """
    path = data_file("spine.json") if path is None else Path(path)
    shown = str(path)
    doc = read_json(path, "spine")
    top = Where(shown, "top level")
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
        where = Where(shown, f"joint {label!r} (joints[{k}])" if label else f"joints[{k}]")
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
        lw = Where(shown, where.entry + ", limits_deg")
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
                    bounded(where, "flexion_axis_offset_mm", x, AXIS_OFFSET_MM, "mm")
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
        vw = Where(shown, f"vertebra {label!r} (vertebrae[{k}])" if label else f"vertebrae[{k}]")
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
            bounded(vw, "size_mm", x, VERTEBRA_SIZE_MM, "mm")
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
        rest=device_array(np.stack([r["rest"] for r in rows])),
        lower=device_array([r["lower"] for r in rows]),
        upper=device_array([r["upper"] for r in rows]),
        disc_heights=device_array(np.asarray([r["disc"] for r in rows]) / 1000.0),
        flexion_axis_offsets=device_array(np.asarray([r["offset"] for r in rows]) / 1000.0),
        vertebra_sizes=device_array(np.reshape(sizes, (-1, 3)) / 1000.0),
    )
