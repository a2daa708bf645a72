"""A marker trial (`MarkerTrial`: times (f,) s, positions (f, n, 3) m in diffbody's world
frame, NaN where missing) and the lab frames marker files are recorded in (`LAB_AXES`,
`lab_rotation`; docs/design.md, section 7). The readers: `_trc` and `_markers` (C3D).
"""

import dataclasses
import math

import numpy as np

from .._body import unknown_name_error

# p_world = R_world_lab @ p_lab.
LAB_AXES: dict[str, np.ndarray] = {
    # lab X forward -> world x; lab Y up -> world z; lab Z right -> world -y.
    "opensim": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
    "z-up": np.eye(3),
}
# Decimal exponent that turns a length in these units into metres.
UNIT_EXPONENTS = {"mm": -3, "cm": -2, "m": 0}
# A marker whose extent over a trial is under STILL_M while the median marker's is over
# MOVING_M does not ride on the body (`MarkerTrial.dead`).
STILL_M = 0.005
MOVING_M = 0.1


class MarkerFileError(ValueError):
    """A marker or marker-set file that cannot be read; the message names the file, the
    line and column (or entry and field) and how to fix it."""


@dataclasses.dataclass(frozen=True, eq=False)
class MarkerTrial:
    """Marker trajectories of one trial, in diffbody's world frame (X forward, Y left, Z up).

    Host-side NumPy data: a trial is read once and then sliced, matched and handed to a
    solver, which takes the arrays it needs.
    """

    names: tuple[str, ...]
    times: np.ndarray  # (n_frames,) s
    positions: np.ndarray  # (n_frames, n_markers, 3) m, world frame, NaN where missing
    rate: float  # Hz, frames per second
    source: str  # the file it came from

    def __post_init__(self):
        times = np.asarray(self.times, dtype=float)
        positions = np.asarray(self.positions, dtype=float)
        names = tuple(self.names)
        if times.ndim != 1:
            raise ValueError(f"MarkerTrial: times must be (n_frames,), got shape {times.shape}")
        if positions.shape != (len(times), len(names), 3):
            raise ValueError(
                f"MarkerTrial: positions must be (n_frames, n_markers, 3) = "
                f"({len(times)}, {len(names)}, 3), got {positions.shape}"
            )
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"MarkerTrial: marker names given twice: {', '.join(twice)}")
        if not (math.isfinite(self.rate) and self.rate > 0):
            raise ValueError(f"MarkerTrial: rate must be > 0 frames per second, got {self.rate}")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "positions", positions)
        object.__setattr__(self, "rate", float(self.rate))

    @property
    def n_frames(self) -> int:
        return len(self.times)

    @property
    def n_markers(self) -> int:
        return len(self.names)

    @property
    def present(self) -> np.ndarray:
        """(n_frames, n_markers) True where the marker was seen."""
        return ~np.isnan(self.positions).any(axis=-1)

    def index(self, name: str) -> int:
        """Column of a marker (KeyError listing the trial's markers, closest first)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise unknown_name_error("marker", name, self.names) from None

    def marker(self, name: str) -> np.ndarray:
        """(n_frames, 3) m, one marker's trajectory."""
        return self.positions[:, self.index(name)]

    def select(self, names) -> "MarkerTrial":
        """The trial restricted to `names`, in that order."""
        idx = [self.index(n) for n in names]
        return dataclasses.replace(
            self, names=tuple(self.names[i] for i in idx), positions=self.positions[:, idx]
        )

    def dead(self) -> dict[str, str]:
        """The markers that carry no measurement, with why: "no data" (a gap in every frame)
        or "does not move" (its extent over the trial is under `STILL_M` while the median
        marker's exceeds `MOVING_M`: a marker left on the floor, or a file that repeats one
        value). A standing trial, where nothing moves, flags none for not moving."""
        seen = self.present
        extent = np.full(self.n_markers, np.nan)
        for k in np.flatnonzero(seen.any(axis=0)):
            p = self.positions[seen[:, k], k]
            extent[k] = np.linalg.norm(p.max(axis=0) - p.min(axis=0))
        moving = np.isfinite(extent).any() and np.nanmedian(extent) > MOVING_M
        out = {}
        for name, e in zip(self.names, extent):
            if np.isnan(e):
                out[name] = "no data"
            elif moving and e < STILL_M:
                out[name] = "does not move"
        return out

    def between(self, t0: float, t1: float) -> "MarkerTrial":
        """The frames with t0 <= time <= t1 (1e-9 s of slack for times printed rounded)."""
        keep = (self.times >= t0 - 1e-9) & (self.times <= t1 + 1e-9)
        return dataclasses.replace(self, times=self.times[keep], positions=self.positions[keep])

    def mean_frame(self) -> "MarkerTrial":
        """One frame: each marker's mean over the frames that see it (a static trial's
        standing posture); NaN for a marker no frame sees. Its time is the mean time."""
        seen = self.present
        count = seen.sum(axis=0)
        total = np.where(seen[..., None], self.positions, 0.0).sum(axis=0)
        mean = np.where(count[:, None] > 0, total / np.maximum(count, 1)[:, None], np.nan)
        time = self.times.mean() if self.n_frames else 0.0
        return dataclasses.replace(self, times=np.array([time]), positions=mean[None])


def lab_rotation(axes) -> np.ndarray:
    """R_world_lab (3, 3) of a LAB_AXES name or of a rotation matrix (checked proper)."""
    if isinstance(axes, str):
        if axes not in LAB_AXES:
            raise unknown_name_error("lab axes", axes, tuple(LAB_AXES))
        return LAB_AXES[axes]
    R = np.asarray(axes, dtype=float)
    if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9):
        raise ValueError(
            f"axes must be a name of LAB_AXES ({', '.join(LAB_AXES)}) or a (3, 3) rotation "
            f"matrix R_world_lab, got {np.array2string(R, precision=4)}"
        )
    if np.linalg.det(R) < 0:
        raise ValueError(
            "axes: the matrix is a reflection (determinant -1), which would swap left and "
            "right; a lab frame maps to the world by a rotation (check the sign of one axis)"
        )
    return R


def zeros_as_gaps(lab: np.ndarray) -> np.ndarray:
    """(f, n, 3) positions with every marker at exactly (0, 0, 0) made a gap (NaN): many
    exporters write "no data" so, and a real marker is never exactly at the lab's origin."""
    lab = np.array(lab, dtype=float)
    lab[np.all(lab == 0.0, axis=-1)] = np.nan
    return lab


def rotate_points(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """R @ p over the last axis of p. A signed permutation (every named lab frame) is
    applied by indexing, so the rotation itself is exact and keeps NaN gaps per marker."""
    if np.all(np.isin(R, (-1.0, 0.0, 1.0))) and np.all(np.abs(R).sum(axis=1) == 1):
        cols = np.argmax(np.abs(R), axis=1)
        return p[..., cols] * R[np.arange(3), cols]
    return p @ R.T
