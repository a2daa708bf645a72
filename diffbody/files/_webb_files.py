"""The image-sequence files of `diffbody webb` (seed 003): the 2D joint positions, the reference
joint's depths and the reflection anchor.

- points CSV: one row per frame; a header names the columns ``<joint>.u`` and ``<joint>.v``
  for every joint of the skeleton (any order; other columns are refused), in pixels;
- root-depth CSV: one number per row (an optional header line), the reference joint's depth
  in metres in each frame;
- anchor JSON: ``{"<start>-><end>": "near" or "far"}`` keyed by part names (0 near and 1 far
  are taken too): the reflections of those parts in one frame.

Every error is a ValueError naming the file, the row or entry and the fix.
"""

import csv
import io
import json
import math
import os

import numpy as np

from ._data_files import read_text

NEAR, FAR = 0, 1  # reflection codes: the part's ending joint is the nearer / farther point


def _text(path: str | os.PathLike, what: str) -> str:
    return read_text(path, f"{what} CSV", ValueError, f"save the {what} as a UTF-8 CSV", unit="row")


def _number(path: str | os.PathLike, line: int, col: int, cell: str) -> float:
    try:
        v = float(cell)
    except ValueError:
        raise ValueError(f"{path}: row {line}, column {col}: not a number: {cell!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{path}: row {line}, column {col}: not a finite number: {cell!r}")
    return v


def read_points(path: str | os.PathLike, names: tuple[str, ...]):
    """(T, J, 2) px from a points CSV (module docstring), columns matched by name."""
    text = _text(path, "image points")
    reader = csv.reader(io.StringIO(text, newline=""))
    rows = [(reader.line_num, [c.strip() for c in row]) for row in reader]
    rows = [(n, r) for n, r in rows if r and any(r)]
    example = ",".join(f"{n}.u,{n}.v" for n in names[:2]) + ",..."
    if not rows:
        raise ValueError(f"{path}: empty; expected a header ({example}) and one row per frame")
    line, header = rows[0]
    if any(";" in c or "\t" in c for c in header):
        raise ValueError(
            f"{path}: row {line}: columns are separated by commas, not semicolons or tabs"
        )
    wanted = {f"{n}.{c}": (j, k) for j, n in enumerate(names) for k, c in enumerate("uv")}
    for col, cell in enumerate(header, start=1):
        if cell not in wanted:
            try:
                float(cell)
                why = "the first row must be a header naming the columns"
            except ValueError:
                why = "no such joint coordinate in the skeleton"
            raise ValueError(f"{path}: row {line}, column {col}: {cell!r}: {why} ({example})")
    if len(set(header)) != len(header):
        twice = next(c for c in header if header.count(c) > 1)
        raise ValueError(f"{path}: row {line}: column {twice!r} is given twice")
    missing = [c for c in wanted if c not in header]
    if missing:
        raise ValueError(
            f"{path}: row {line}: no column {missing[0]!r}; every joint needs .u and .v"
        )
    if len(rows) < 2:
        raise ValueError(f"{path}: a header but no frames")
    out = np.zeros((len(rows) - 1, len(names), 2))
    for i, (line, row) in enumerate(rows[1:]):
        if len(row) != len(header):
            raise ValueError(
                f"{path}: row {line}, column {min(len(row), len(header)) + 1}: expected "
                f"{len(header)} columns, got {len(row)}"
            )
        for col, (name, cell) in enumerate(zip(header, row), start=1):
            j, k = wanted[name]
            out[i, j, k] = _number(path, line, col, cell)
    return out


def read_depths(path: str | os.PathLike, n_frames: int):
    """(T,) m from a root-depth CSV: one number > 0 per row, an optional header."""
    text = _text(path, "depths")
    reader = csv.reader(io.StringIO(text, newline=""))
    values = []
    for row in reader:
        line = reader.line_num
        cells = [c.strip() for c in row if c.strip()]
        if not cells:
            continue
        if len(cells) != 1:
            raise ValueError(
                f"{path}: row {line}: expected one depth (m) per row, got {len(cells)} cells"
            )
        try:
            v = float(cells[0])
        except ValueError:
            if not values and line == 1:
                continue  # a header
            raise ValueError(f"{path}: row {line}, column 1: not a number: {cells[0]!r}") from None
        if not (math.isfinite(v) and v > 0):
            raise ValueError(
                f"{path}: row {line}, column 1: depth {cells[0]!r} must be a finite number > 0 "
                "(m; the reference joint lies in front of the camera)"
            )
        values.append(v)
    if len(values) != n_frames:
        raise ValueError(
            f"{path}: {len(values)} depths for {n_frames} frames of image points; "
            "give one per frame"
        )
    return np.asarray(values)


ANCHOR_EXAMPLE = '{"center_hip->left_hip": "near", "left_hip->left_knee": "far", ...}'


def read_anchor(path: str | os.PathLike, part_names: tuple[str, ...]):
    """(P,) reflection codes from an anchor JSON (module docstring): NEAR 0 or FAR 1 for the
    parts it names, -1 (left to continuity) for the others; errors name the file, the
    entry and the fix."""
    text = read_text(path, "anchor JSON", ValueError, "save the anchor as a UTF-8 JSON file")

    def pairs(items):
        seen = set()
        for key, _ in items:
            if key in seen:
                raise ValueError(f"{path}: entry {key!r} is given twice; keep one")
            seen.add(key)
        return dict(items)

    try:
        doc = json.loads(text, object_pairs_hook=pairs)
    except json.JSONDecodeError as e:
        raise ValueError(
            f"{path}: not JSON (line {e.lineno}, column {e.colno}: {e.msg}); "
            f"expected an object such as {ANCHOR_EXAMPLE}"
        ) from None
    if not isinstance(doc, dict):
        kinds = {list: "an array", str: "a string", bool: "true or false", type(None): "null"}
        kind = kinds.get(type(doc), "a number")
        raise ValueError(
            f"{path}: expected a JSON object of part reflections, got {kind}; e.g. {ANCHOR_EXAMPLE}"
        )
    if not doc:
        raise ValueError(
            f"{path}: no part's reflection given; name at least one part, e.g. {ANCHOR_EXAMPLE}"
        )
    codes = {"near": NEAR, "far": FAR}
    anchor = np.full(len(part_names), -1)
    for key, value in doc.items():
        if key not in part_names:
            raise ValueError(
                f"{path}: entry {key!r}: no such part of the skeleton; parts are named "
                f"<start>-><end> by their joints: {', '.join(part_names)}"
            )
        if isinstance(value, str) and value.strip().lower() in codes:
            anchor[part_names.index(key)] = codes[value.strip().lower()]
        elif type(value) is int and value in (NEAR, FAR):
            anchor[part_names.index(key)] = value
        else:
            raise ValueError(
                f'{path}: entry {key!r}: the reflection must be "near" or "far" '
                f"(or 0 near, 1 far), got {json.dumps(value)}; leave a part out when unknown"
            )
    return anchor
