"""Reading motion-capture marker files (docs/design.md, section 7): C3D through ezc3d
(`read_c3d`), and any marker file by its extension (`read_markers`: TRC through `_trc`), into
a `MarkerTrial` in diffbody's world frame and metres.
"""

from pathlib import Path

import numpy as np

from ._marker_trial import (
    UNIT_EXPONENTS,
    MarkerFileError,
    MarkerTrial,
    lab_rotation,
    rotate_points,
    zeros_as_gaps,
)
from ._trc import read_trc


def read_c3d(path, axes="opensim", zero_is_gap: bool = True) -> MarkerTrial:
    """Read the marker points of a C3D file through ezc3d (the optional extra ``c3d``).

    Points whose residual is negative (the C3D flag for "not seen") are NaN, and so, unless
    `zero_is_gap` is False, are points at exactly (0, 0, 0) (`zeros_as_gaps`). Units come
    from POINT:UNITS (mm, cm or m). Many C3D labs record Z up: pass ``axes="z-up"`` (or the
    lab's own rotation) for those.
    """
    try:
        import ezc3d
    except ImportError:
        raise ImportError(
            "read_c3d needs ezc3d, which diffbody does not install by default: "
            "pip install diffbody[c3d]  (or pip install ezc3d)"
        ) from None
    R = lab_rotation(axes)
    shown = str(path)
    if not Path(path).is_file():
        raise FileNotFoundError(f"{shown}: no such marker file")
    try:
        c3d = ezc3d.c3d(str(path))
    except Exception as e:  # ezc3d raises plain RuntimeErrors with its own wording
        raise MarkerFileError(f"{shown}: ezc3d cannot read it as C3D: {e}") from None
    point = c3d["parameters"]["POINT"]
    names = list(point["LABELS"]["value"])
    for extra in ("LABELS2", "LABELS3"):  # files with more than 255 points continue here
        if extra in point:
            names += list(point[extra]["value"])
    points = np.asarray(c3d["data"]["points"], dtype=float)  # (4, n_markers, n_frames)
    if len(names) < points.shape[1]:
        raise MarkerFileError(
            f"{shown}: parameter POINT:LABELS names {len(names)} of its {points.shape[1]} "
            "points; label every point"
        )
    names = tuple(n.strip() for n in names[: points.shape[1]])
    given = point["UNITS"]["value"] if "UNITS" in point else []
    units = str(given[0]).strip().lower() if len(given) else "mm"  # C3D's default unit
    if units not in UNIT_EXPONENTS:
        raise MarkerFileError(
            f"{shown}: parameter POINT:UNITS: unknown units {units!r}; use one of mm, cm, m"
        )
    rate = float(np.asarray(point["RATE"]["value"]).ravel()[0])
    lab = np.transpose(points[:3], (2, 1, 0)) * 10.0 ** UNIT_EXPONENTS[units]
    residuals = np.asarray(c3d["data"]["meta_points"]["residuals"], dtype=float)
    lab[np.transpose(residuals[0] < 0)] = np.nan
    lab[np.isnan(lab).any(axis=-1)] = np.nan
    if zero_is_gap:
        lab = zeros_as_gaps(lab)
    first = int(c3d["header"]["points"]["first_frame"])
    times = (first + np.arange(lab.shape[0])) / rate
    return MarkerTrial(
        names=names, times=times, positions=rotate_points(R, lab), rate=rate, source=shown
    )


def read_markers(path, axes="opensim", zero_is_gap: bool = True) -> MarkerTrial:
    """Read a marker file by its extension: .trc (`read_trc`) or .c3d (`read_c3d`); a
    marker at exactly (0, 0, 0) is a gap unless `zero_is_gap` is False."""
    suffix = Path(path).suffix.lower()
    if suffix == ".trc":
        return read_trc(path, axes, zero_is_gap)
    if suffix == ".c3d":
        return read_c3d(path, axes, zero_is_gap)
    raise MarkerFileError(
        f"{path}: unknown marker file type {suffix or '(no extension)'!r}; "
        "diffbody reads .trc and .c3d files"
    )
