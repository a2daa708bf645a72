"""TRC marker files (Motion Analysis's track-row-column text, as OpenSim reads and writes it;
docs/design.md, section 7): `read_trc` into a `MarkerTrial` in the world frame and metres,
`write_trc` back in a lab frame and mm, cm or m.

Tab separated. Line 1 starts with ``PathFileType``; line 2 names the header values of line 3
(DataRate, NumFrames, NumMarkers, Units, ...; read by name); line 4 holds ``Frame#``,
``Time`` and one marker name per X/Y/Z triple; line 5 the ``X1 Y1 Z1 ...`` labels; the data
rows follow. An empty cell, a ``nan``, or a row shorter than the header is a gap (NaN).
Every error is a `MarkerFileError` naming the file, the line and the column (1-based, in TRC
cells: column 1 is ``Frame#``) and the fix. Units are converted on the decimal text, so
`write_trc` then `read_trc` gives back every float exactly.

Labels may carry a subject prefix, as Vicon Nexus writes them (``Subject01:LASI``): the
readers keep the part after the last ``:`` (`marker_labels`), so one marker set serves every
subject; ``strip_prefix=False`` keeps the labels whole.
"""

import math
import re
from decimal import Decimal
from pathlib import Path

import numpy as np

from ._data_files import read_text
from ._marker_trial import (
    UNIT_EXPONENTS,
    MarkerFileError,
    MarkerTrial,
    lab_rotation,
    rotate_points,
    zeros_as_gaps,
)

TRC_REQUIRED_KEYS = ("DataRate", "NumFrames", "NumMarkers", "Units")
TRC_KEYS = (  # the layout OpenSim's TRCFileAdapter writes and requires
    "DataRate",
    "CameraRate",
    "NumFrames",
    "NumMarkers",
    "Units",
    "OrigDataRate",
    "OrigDataStartFrame",
    "OrigNumFrames",
)
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.rstrip("\r\n").split("\t")]


def _shift_decimal(text: str, exponent: int) -> str:
    """A number's text times 10**exponent, still as text (exact)."""
    if exponent == 0:
        return text
    mantissa, _, power = text.lower().partition("e")
    return f"{mantissa}e{int(power or 0) + exponent}"


def _number(path: str, line: int, col: int, cell: str, what: str, exponent: int = 0) -> float:
    """The value of one TRC cell; anything but a finite decimal number (or nan) is an error
    naming the file, line and column."""
    if _NUMBER.fullmatch(cell):
        return float(_shift_decimal(cell, exponent))
    if cell.lower() == "nan":
        return math.nan
    raise MarkerFileError(
        f"{path}: line {line}, column {col} ({what}): expected a number, found {cell!r}; "
        "write a decimal number, or leave the cell empty where the marker is missing"
    )


def marker_labels(labels, strip_prefix: bool, shown: str, where: str) -> tuple[str, ...]:
    """A file's marker labels, each without its subject prefix (the part up to the last
    ``:``; a label with nothing after its last ``:`` is kept whole) unless `strip_prefix` is
    False.

    Args:
        labels: the labels as the file gives them (surrounding spaces already removed).
        strip_prefix: drop the prefixes.
        shown: the file, for the errors.
        where: where the file holds the labels ("line 4", "parameter POINT:LABELS").

    Raises:
        MarkerFileError: a label given twice, or two labels that become one once stripped
            (two subjects in one file), named with the fix.
    """
    labels = tuple(labels)
    twice = sorted({n for n in labels if labels.count(n) > 1})
    if twice:
        raise MarkerFileError(
            f"{shown}: {where}: marker names given twice: {', '.join(twice)}; rename one of each"
        )
    if not strip_prefix:
        return labels
    stripped = tuple(n.rpartition(":")[2] or n for n in labels)
    clashes = {}
    for label, name in zip(labels, stripped):
        clashes.setdefault(name, []).append(label)
    clashes = {name: group for name, group in clashes.items() if len(group) > 1}
    if clashes:
        shown_clashes = "; ".join(
            f"{' and '.join(repr(g) for g in group)} are both {name!r}"
            for name, group in sorted(clashes.items())
        )
        raise MarkerFileError(
            f"{shown}: {where}: {shown_clashes} once the 'Subject:' prefixes are stripped "
            "(two subjects in one file?); read it with strip_prefix=False to keep the "
            "prefixes, then select one subject's markers (MarkerTrial.select) and rename them"
        )
    return stripped


def read_trc(
    path, axes="opensim", zero_is_gap: bool = True, *, strip_prefix: bool = True
) -> MarkerTrial:
    """Read a TRC marker file (module docstring) into the world frame, in metres.

    Args:
        path: the .trc file.
        axes: the lab frame, a name of `LAB_AXES` or a (3, 3) rotation R_world_lab; None is
            OpenSim's (Y up), the frame TRC files are written in.
        zero_is_gap: a marker at exactly (0, 0, 0) is a gap, as many exporters write one
            (`zeros_as_gaps`); False keeps it as a measurement.
        strip_prefix: drop a ``Subject:`` prefix from every label (`marker_labels`).

    Returns:
        `MarkerTrial`; missing markers are NaN.
    """
    R = lab_rotation("opensim" if axes is None else axes)
    shown = str(path)
    text = read_text(path, "marker", MarkerFileError, "a TRC file is tab-separated text")
    lines = text.splitlines()

    def fail(line: int, message: str, col: int | None = None, what: str = "") -> MarkerFileError:
        at = (f", column {col}" if col else "") + (f" ({what})" if what else "")
        return MarkerFileError(f"{shown}: line {line}{at}: {message}")

    if len(lines) < 5:
        raise fail(
            len(lines) + 1,
            f"the header ends after {len(lines)} line(s); a TRC file has 5 header lines "
            "(PathFileType; the header names; their values; Frame#, Time and the marker "
            "names; the X1 Y1 Z1 labels) before its data",
        )
    if _cells(lines[0])[0] != "PathFileType":
        raise fail(1, f"expected 'PathFileType' first, found {lines[0][:40]!r}: not a TRC file")
    # Keys and values are paired in order, empty cells dropped (as OpenSim does): some
    # writers pad one line with extra tabs.
    keys = [(c, k) for c, k in enumerate(_cells(lines[1]), start=1) if k]
    values = [(c, v) for c, v in enumerate(_cells(lines[2]), start=1) if v]
    if len(values) < len(keys):
        raise fail(
            3,
            f"{len(values)} header values for the {len(keys)} names of line 2 "
            f"({', '.join(k for _, k in keys)}); give one value per name",
        )
    header = {key: value for (_, key), value in zip(keys, values)}
    for key in TRC_REQUIRED_KEYS:
        if key not in header:
            raise fail(
                2, f"no {key!r} among the header names; line 2 must name " + ", ".join(TRC_KEYS)
            )
    col, units = header["Units"]
    if units.lower() not in UNIT_EXPONENTS:
        raise fail(3, f"unknown units {units!r}; use one of mm, cm, m", col, "Units")
    exponent = UNIT_EXPONENTS[units.lower()]
    suffix = f"e{exponent}" if exponent else ""  # to metres on the decimal text: exact
    counts = {}
    for key in ("NumFrames", "NumMarkers"):
        col, value = header[key]
        try:
            counts[key] = int(value)
        except ValueError:
            counts[key] = -1
        if counts[key] < 0:
            raise fail(3, f"expected a whole number >= 0, found {value!r}", col, key)
    col, value = header["DataRate"]
    rate = _number(shown, 3, col, value, "DataRate")
    if not rate > 0:
        raise fail(3, f"must be > 0 frames per second, found {value!r}", col, "DataRate")

    labels = _cells(lines[3])
    if labels[:2] != ["Frame#", "Time"]:
        raise fail(4, f"expected 'Frame#' and 'Time' in columns 1-2, found {labels[:2]}")
    names = tuple(n for n in labels[2:] if n)
    n_markers = counts["NumMarkers"]
    if len(names) != n_markers:
        raise fail(
            4,
            f"{len(names)} marker names, but NumMarkers (line 3, column "
            f"{header['NumMarkers'][0]}) says {n_markers}; make them agree",
        )
    names = marker_labels(names, strip_prefix, shown, "line 4")
    n_cells = 2 + 3 * n_markers
    xyz = [c for c in _cells(lines[4]) if c]
    if len(xyz) != 3 * n_markers:
        raise fail(
            5,
            f"{len(xyz)} coordinate labels (X1 Y1 Z1 ...), expected 3 per marker = {3 * n_markers}",
        )

    first = 5
    while first < len(lines) and not lines[first].strip():
        first += 1  # OpenSim leaves a blank line before the data
    last = len(lines)
    while last > first and not lines[last - 1].strip():
        last -= 1
    rows = lines[first:last]
    if len(rows) != counts["NumFrames"]:
        raise fail(
            3,
            f"says {counts['NumFrames']} frames, but the data has {len(rows)} rows "
            f"(lines {first + 1}-{last}); make them agree",
            header["NumFrames"][0],
            "NumFrames",
        )
    times = np.empty(len(rows))
    lab = np.full((len(rows), n_markers * 3), np.nan)
    for r, line in enumerate(rows):
        ln = first + r + 1
        cells = _cells(line)
        if len(cells) > n_cells and any(cells[n_cells:]):
            extra = n_cells + next(i for i, c in enumerate(cells[n_cells:]) if c) + 1
            raise fail(
                ln,
                f"a value beyond the {n_markers} markers of line 4 (found {cells[extra - 1]!r}); "
                "each row holds Frame#, Time and X, Y, Z per marker",
                extra,
            )
        if len(cells) < 2 or not cells[1]:
            raise fail(ln, "missing; every row needs its time in seconds", 2, "Time")
        times[r] = _number(shown, ln, 2, cells[1], "Time")
        if math.isnan(times[r]):
            raise fail(ln, "nan; every row needs its time in seconds", 2, "Time")
        data = cells[2:n_cells]
        for k, c in enumerate(data):  # inline checks: this loop runs for every cell
            if c and not _NUMBER.fullmatch(c) and c.lower() != "nan":
                _number(shown, ln, 3 + k, c, f"{names[k // 3]} {'XYZ'[k % 3]}")  # raises
        lab[r, : len(data)] = [
            math.nan
            if not c or c[0] in "nN"
            else float(c + suffix)
            if "e" not in c and "E" not in c
            else float(_shift_decimal(c, exponent))
            for c in data
        ]
    lab = lab.reshape(len(rows), n_markers, 3)
    lab[np.isnan(lab).any(axis=-1)] = np.nan  # a marker with any coordinate missing is missing
    if zero_is_gap:
        lab = zeros_as_gaps(lab)
    return MarkerTrial(
        names=names, times=times, positions=rotate_points(R, lab), rate=rate, source=shown
    )


def _format_length(x: float, exponent: int) -> str:
    """Text of a length in metres written in units 10**-exponent m, exactly invertible by
    `_number` (the decimal point of repr(x) moved, no rounding)."""
    if math.isnan(x):
        return ""
    if exponent == 0:
        return repr(x)
    d = Decimal(repr(x)).scaleb(-exponent)
    text = format(d, "f")
    return text.rstrip("0").rstrip(".") if "." in text else text


def write_trc(path, trial: MarkerTrial, axes="opensim", units: str = "mm") -> None:
    """Write a trial as a TRC file in OpenSim's layout (OpenSim's TRCFileAdapter reads it):
    the world positions turned into the lab frame `axes`, in `units` (mm, cm or m), gaps
    as empty cells. Every number is written exactly: `read_trc` with the same `axes` gives
    back the same floats."""
    if units not in UNIT_EXPONENTS:
        raise ValueError(f"write_trc: unknown units {units!r}; use one of mm, cm, m")
    R = lab_rotation(axes)
    lab = rotate_points(R.T, trial.positions)
    lab[np.isnan(lab).any(axis=-1)] = np.nan
    exponent = UNIT_EXPONENTS[units]
    n, m = trial.n_frames, trial.n_markers
    bad = [c for c in trial.names if not c or c != c.strip() or "\t" in c or "\n" in c]
    if bad:
        raise ValueError(
            f"write_trc: marker names {bad!r} cannot be written to a TRC file (empty, or with "
            "tabs, line breaks or surrounding spaces)"
        )
    if not np.all(np.isfinite(trial.times)) or np.isinf(trial.positions).any():
        raise ValueError(
            "write_trc: times must be finite and positions finite or NaN (a gap); "
            f"trial {trial.source!r} has an infinite or NaN time, or an infinite position"
        )
    rate = repr(trial.rate)
    out = [
        f"PathFileType\t4\t(X/Y/Z)\t{Path(path).name}",
        "\t".join(TRC_KEYS),
        "\t".join([rate, rate, str(n), str(m), units, rate, "1", str(n)]),
        "\t".join(["Frame#", "Time"] + [f"{name}\t\t" for name in trial.names]),
        "\t\t" + "".join(f"X{i}\tY{i}\tZ{i}\t" for i in range(1, m + 1)),
        "",
    ]
    for f in range(n):
        cells = [str(f + 1), repr(float(trial.times[f]))]
        cells += [_format_length(float(v), exponent) for v in lab[f].ravel()]
        out.append("\t".join(cells) + "\t")  # OpenSim ends every row with a tab
    Path(path).write_text("\n".join(out) + "\n", encoding="utf-8")
