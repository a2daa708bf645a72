"""Skeleton files: the joint tree of an image sequence (seed 003), a JSON object
``{"format": "diffbody.joint_tree/1", "joints": [{"name": "center_hip", "parent": null},
{"name": "left_hip", "parent": "center_hip"}, ...]}``, parents before their children."""

import json
from pathlib import Path

from ._data_files import read_text

FORMAT = "diffbody.joint_tree/1"


def read_skeleton(path) -> list[tuple[str, str | None]]:
    """[(joint name, parent name or None)] of a skeleton file; every error is a ValueError
    naming the file, the entry and the field."""
    text = read_text(path, "skeleton JSON", ValueError, "save the skeleton as UTF-8 JSON")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(
            f"{path}: not valid JSON: {e.msg} at line {e.lineno} column {e.colno}"
        ) from None
    example = '{"joints": [{"name": "center_hip", "parent": null}, ...]}'
    if not isinstance(doc, dict) or not isinstance(doc.get("joints"), list):
        raise ValueError(f"{path}: expected an object with a list 'joints', e.g. {example}")
    fmt = doc.get("format", FORMAT)
    if fmt != FORMAT:
        raise ValueError(f"{path}: field 'format': expected {FORMAT!r}, got {fmt!r}")
    joints = []
    for i, entry in enumerate(doc["joints"]):
        where = f"{path}: joints[{i}]"
        if not isinstance(entry, dict) or set(entry) != {"name", "parent"}:
            raise ValueError(
                f"{where}: expected exactly the fields 'name' and 'parent', got {entry!r}"
            )
        name, parent = entry["name"], entry["parent"]
        if not isinstance(name, str):
            raise ValueError(f"{where}, field 'name': expected a string, got {name!r}")
        if parent is not None and not isinstance(parent, str):
            raise ValueError(
                f"{where} ({name!r}), field 'parent': expected a joint name or null, got {parent!r}"
            )
        joints.append((name, parent))
    return joints


def write_skeleton(joints: list[tuple[str, str | None]], path) -> None:
    """Write [(joint name, parent name or None)] as a skeleton file."""
    doc = {"format": FORMAT, "joints": [{"name": n, "parent": p} for n, p in joints]}
    Path(path).write_text(json.dumps(doc, indent=1) + "\n")
