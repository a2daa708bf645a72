"""OpenSim motion files (.mot, OpenSim's "storage" format; .sto is the same): `write_mot` and
`read_mot`, a time column and named columns of numbers.

Layout, as OpenSim 4 writes and reads it (its STOFileAdapter; `opensim.TimeSeriesTable`):

    <name>
    version=1
    nRows=<rows>
    nColumns=<columns, time included>
    inDegrees=yes
    endheader
    time<TAB><label><TAB>...
    <time><TAB><value><TAB>...

Before ``endheader`` the first line is the table's name; every other line is ``key=value``
or free text (OpenSim's own files carry comment lines such as "Units are S.I. units").
``inDegrees`` says the unit of the angle columns (yes: degrees; no: radians); other columns
(OpenSim's pelvis_tx, ...) are in metres whatever it says. Cells are separated by tabs (or,
in a file without tabs, by spaces). Every read error is a `MotionFileError` naming the file,
the line (1-based) and the fix. `write_mot` writes each float's shortest exact text, so
`read_mot` gives back the same floats, and replaces the file atomically.
"""

import math
import os
import tempfile
from pathlib import Path

import numpy as np

from ._data_files import read_text

MOT_VERSION = 1


class MotionFileError(ValueError):
    """A motion file that cannot be read, with the file, the line and the fix."""


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write `text` (UTF-8) to `path` by way of a temporary file in the same folder that then
    replaces it: a reader sees the old file or the new one, never half of one."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _bad_label(label: str) -> bool:
    """Empty, spaces around it, or whitespace but plain spaces (tabs, line breaks)."""
    return not label or label != label.strip() or any(c.isspace() and c != " " for c in label)


def write_mot(
    path: str | Path,
    times,
    columns: dict[str, object],
    *,
    name: str = "diffbody",
    in_degrees: bool = True,
) -> Path:
    """Write an OpenSim motion file (module docstring), atomically.

    Args:
        path: the .mot (or .sto) file to write; its folder must exist.
        times: (n,) seconds, finite and increasing.
        columns: label -> (n,) values, in the dict's order (e.g. `joint_angles` of every
            frame, degrees). NaN is written as ``NaN``.
        name: the table's name, the header's first line.
        in_degrees: the header's ``inDegrees`` (yes: the angle columns are degrees).

    Returns:
        The path written.
    """
    times = np.asarray(times, dtype=float)
    if times.ndim != 1:
        raise ValueError(f"write_mot: times must be one-dimensional, got shape {times.shape}")
    if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise ValueError("write_mot: times must be finite and strictly increasing")
    if _bad_label(name) or name.lower() == "endheader" or "=" in name:
        raise ValueError(
            f"write_mot: name {name!r} cannot be a header's first line (empty, with '=', "
            "tabs, line breaks or surrounding spaces)"
        )
    labels = list(columns)
    bad = [c for c in labels if not isinstance(c, str) or _bad_label(c) or c.lower() == "time"]
    if bad:
        raise ValueError(
            f"write_mot: column labels {bad!r} cannot be written (not text, empty, 'time', "
            "or with tabs, line breaks or surrounding spaces)"
        )
    values = []
    for label in labels:
        v = np.asarray(columns[label], dtype=float)
        if v.shape != times.shape:
            raise ValueError(
                f"write_mot: column {label!r} has shape {v.shape}; every column needs one "
                f"value per time, shape {times.shape}"
            )
        if np.isinf(v).any():
            raise ValueError(f"write_mot: column {label!r} has an infinite value")
        values.append(v)
    data = np.stack([times] + values, axis=1) if values else times[:, None]

    def cell(x: float) -> str:
        return "NaN" if math.isnan(x) else repr(float(x))

    lines = [
        name,
        f"version={MOT_VERSION}",
        f"nRows={len(times)}",
        f"nColumns={data.shape[1]}",
        f"inDegrees={'yes' if in_degrees else 'no'}",
        "endheader",
        "\t".join(["time"] + labels),
    ]
    lines += ["\t".join(cell(x) for x in row) for row in data]
    return write_text_atomic(path, "\n".join(lines) + "\n")


def _cells(line: str) -> list[str]:
    line = line.strip()
    return [c.strip() for c in line.split("\t")] if "\t" in line else line.split()


def read_mot(path: str | Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read an OpenSim motion or storage file (module docstring), OpenSim's own included.

    Returns:
        (times (n,) in seconds, label -> (n,) values in the file's column order). The values
        are as stored: angles in degrees where the header says ``inDegrees=yes``.
    """
    shown = str(path)
    text = read_text(path, "motion", MotionFileError, "a motion file is tab-separated text")
    lines = text.splitlines()

    def fail(line: int, message: str) -> MotionFileError:
        return MotionFileError(f"{shown}: line {line}: {message}")

    end = next((k for k, s in enumerate(lines) if s.strip().lower() == "endheader"), None)
    if end is None:
        raise fail(
            len(lines) + 1,
            "no 'endheader' line; an OpenSim motion file starts with a header (its name, "
            "version=1, nRows=, nColumns=, inDegrees=yes) that ends with a line 'endheader'",
        )
    header: dict[str, tuple[int, str]] = {}
    for k, s in enumerate(lines[:end], start=1):
        key, eq, value = s.partition("=")
        if eq and k > 1:
            header[key.strip()] = (k, value.strip())
    counts = {}
    for key in ("nRows", "nColumns"):
        if key in header:
            k, value = header[key]
            try:
                counts[key] = int(value)
            except ValueError:
                counts[key] = -1
            if counts[key] < 0:
                raise fail(k, f"{key}={value!r}: expected a whole number >= 0")
    if end + 1 >= len(lines) or not lines[end + 1].strip():
        raise fail(
            end + 2,
            "expected the column labels after 'endheader' ('time', then one label per "
            "column, tab separated)",
        )
    labels = _cells(lines[end + 1])
    if labels[0].lower() != "time":
        raise fail(end + 2, f"the first column must be 'time', found {labels[0]!r}")
    twice = sorted({c for c in labels if labels.count(c) > 1})
    if twice:
        raise fail(end + 2, f"column labels {twice} appear more than once; make them unique")
    if "nColumns" in counts and counts["nColumns"] != len(labels):
        k = header["nColumns"][0]
        raise fail(
            end + 2,
            f"{len(labels)} column labels, but nColumns (line {k}) says {counts['nColumns']} "
            "(time included); make them agree",
        )
    rows, numbers = [], []  # the data rows and their line numbers (1-based)
    for k, s in enumerate(lines[end + 2 :], start=end + 3):
        if not s.strip():
            continue
        cells = _cells(s)
        if len(cells) != len(labels):
            raise fail(
                k,
                f"{len(cells)} values for {len(labels)} columns; give one number per column "
                "(a truncated or hand-edited row?)",
            )
        row = []
        for c, (cell, label) in enumerate(zip(cells, labels), start=1):
            try:
                row.append(float(cell))
            except ValueError:
                raise fail(k, f"column {c} ({label}): expected a number, found {cell!r}") from None
        rows.append(row)
        numbers.append(k)
    if "nRows" in counts and counts["nRows"] != len(rows):
        k = header["nRows"][0]
        raise fail(
            k,
            f"nRows={counts['nRows']} but the file has {len(rows)} data rows; fix nRows, or "
            "look for a truncated file",
        )
    data = np.asarray(rows, dtype=float).reshape(len(rows), len(labels))
    if not np.all(np.isfinite(data[:, 0])):
        bad = int(np.flatnonzero(~np.isfinite(data[:, 0]))[0])
        raise fail(numbers[bad], "the time is not a finite number")
    return data[:, 0], {label: data[:, c] for c, label in enumerate(labels) if c > 0}
