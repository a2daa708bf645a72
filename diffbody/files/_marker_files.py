"""Reading motion-capture marker files (docs/design.md, section 7): C3D through ezc3d
(`read_c3d`), and any marker file by its extension (`read_markers`: TRC through `_trc`), into
a `MarkerTrial` in diffbody's world frame and metres.

The lab's axes default to the file's own: a TRC file is in OpenSim's (Y up); a C3D file says
which lab axis is up on screen in POINT:Y_SCREEN (Vicon and Qualisys write "+Z") and which
points right in POINT:X_SCREEN, from which `c3d_screen_axes` builds R_world_lab; a C3D
without them is taken as Z up with the lab's X forward. An explicit `axes` always wins.
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
from ._trc import marker_labels, read_trc

_LAB_AXIS = {"X": 0, "Y": 1, "Z": 2}


def _screen_axis(text: str, parameter: str, shown: str) -> np.ndarray:
    """The signed lab axis (3,) that a C3D screen parameter names ("+Z", "-X", "Y")."""
    t = text.strip().upper()
    sign = -1.0 if t.startswith("-") else 1.0
    letter = t[1:] if t[:1] in "+-" and t else t
    if letter not in _LAB_AXIS:
        raise MarkerFileError(
            f"{shown}: parameter POINT:{parameter}: expected a signed lab axis such as '+Z' "
            f"or '-X', found {text!r}; fix the parameter, or pass the lab's axes (axes=)"
        )
    axis = np.zeros(3)
    axis[_LAB_AXIS[letter]] = sign
    return axis


def c3d_screen_axes(x_screen: str | None, y_screen: str | None, source: str = "C3D") -> np.ndarray:
    """R_world_lab (3, 3) of a C3D's POINT:X_SCREEN and POINT:Y_SCREEN (p_world = R @ p_lab).

    The C3D standard's screen view shows lab axis `y_screen` pointing up and `x_screen`
    pointing right. Diffbody's world is X forward, Y left, Z up; its view from the subject's
    right side shows +Z up and +X (forward) to the right. So the world's up is `y_screen`,
    its forward `x_screen` (a subject walking across the screen from left to right faces
    +X), and its left up x forward. Vicon and Qualisys write ("+X", "+Z"): the identity;
    OpenSim's Y-up frame is ("+X", "+Y"): `LAB_AXES["opensim"]`.

    Without `y_screen` the lab is taken as Z up. Without `x_screen`, forward is the lab's +X
    (+Y when X is up): Vicon and Qualisys labs, and OpenSim's, run their walkways along X.
    Forward is a convention, not a measurement: a subject walking along another lab axis
    is fitted facing that way all the same (the whole body's placement is an unknown).

    Args:
        x_screen, y_screen: the parameters' text ("+X", "-Z", ...), or None where absent.
        source: the file, for the errors.

    Raises:
        MarkerFileError: a value that names no lab axis, or both naming the same one.
    """
    up = _screen_axis(y_screen, "Y_SCREEN", source) if y_screen else np.array([0.0, 0.0, 1.0])
    if x_screen:
        forward = _screen_axis(x_screen, "X_SCREEN", source)
        if abs(forward @ up) > 0:
            raise MarkerFileError(
                f"{source}: parameters POINT:X_SCREEN ({x_screen!r}) and POINT:Y_SCREEN "
                f"({y_screen or 'absent: Z up'!r}) name the same lab axis; the screen's right "
                "and up must be two different axes: fix one, or pass the lab's axes (axes=)"
            )
    else:
        forward = np.array([0.0, 1.0, 0.0]) if up[0] else np.array([1.0, 0.0, 0.0])
    return np.stack([forward, np.cross(up, forward), up])


def _parameter_text(group: dict, name: str) -> str | None:
    """The first value of a C3D parameter as stripped text; None where absent or blank."""
    if name not in group:
        return None
    value = group[name]["value"]
    text = str(value[0]).strip() if len(value) else ""
    return text or None


def read_c3d(
    path, axes=None, zero_is_gap: bool = True, *, strip_prefix: bool = True
) -> MarkerTrial:
    """Read the marker points of a C3D file through ezc3d (the optional extra ``c3d``).

    Args:
        path: the .c3d file.
        axes: the lab frame, a name of `LAB_AXES` or a (3, 3) rotation R_world_lab; None
            (default): the file's POINT:X_SCREEN and POINT:Y_SCREEN (`c3d_screen_axes`),
            Z up with the lab's X forward where it has neither.
        zero_is_gap: a marker at exactly (0, 0, 0) is a gap (`zeros_as_gaps`); False keeps
            it as a measurement.
        strip_prefix: drop a ``Subject:`` prefix from every label, as Vicon writes them
            (``Subject01:LASI`` reads as ``LASI``; `marker_labels`).

    Returns:
        `MarkerTrial` in the world frame and metres. Points whose residual is negative (the
        C3D flag for "not seen") are NaN. Units come from POINT:UNITS (mm, cm or m; mm when
        absent, the C3D default).
    """
    try:
        import ezc3d
    except ImportError:
        raise ImportError(
            "read_c3d needs ezc3d, which diffbody does not install by default: "
            "pip install diffbody[c3d]  (or pip install ezc3d)"
        ) from None
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
    names = marker_labels(names, strip_prefix, shown, "parameter POINT:LABELS")
    if axes is None:
        x_screen, y_screen = (_parameter_text(point, p) for p in ("X_SCREEN", "Y_SCREEN"))
        R = c3d_screen_axes(x_screen, y_screen, shown)
    else:
        R = lab_rotation(axes)
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


def read_markers(
    path, axes=None, zero_is_gap: bool = True, *, strip_prefix: bool = True
) -> MarkerTrial:
    """Read a marker file by its extension: .trc (`read_trc`) or .c3d (`read_c3d`).

    Args:
        path: the marker file.
        axes: the lab frame (a name of `LAB_AXES` or a (3, 3) rotation R_world_lab); None
            (default): the format's own, OpenSim's Y up for TRC, the file's screen axes or
            Z up for C3D (module docstring).
        zero_is_gap: a marker at exactly (0, 0, 0) is a gap unless False.
        strip_prefix: drop a ``Subject:`` prefix from every label.
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".trc":
        return read_trc(path, axes, zero_is_gap, strip_prefix=strip_prefix)
    if suffix == ".c3d":
        return read_c3d(path, axes, zero_is_gap, strip_prefix=strip_prefix)
    raise MarkerFileError(
        f"{path}: unknown marker file type {suffix or '(no extension)'!r}; "
        "diffbody reads .trc and .c3d files"
    )
