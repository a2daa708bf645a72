"""OpenSim as the motion-capture peer: its Scale and InverseKinematics tools run on the
Gait2354 example files (data/mocap, see its README), timed, their marker
errors parsed.

`opensim` (pip install opensim, 4.6) is a benchmark-only dependency: every function that
needs it returns None when it is not importable. The setup files name their inputs by
relative file names, so each tool runs in a temporary folder holding copies of the files.
`ik_tasks` and `read_trc_lab` need no OpenSim.
"""

import contextlib
import os
import shutil
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
OPENSIM_DIR = REPO / "data" / "mocap"  # OpenSim's example files, copied with their source
SCALE_SETUP = "subject01_Setup_Scale.xml"
IK_SETUP = "subject01_Setup_IK.xml"
IK_REFERENCE = "subject01_walk1_ik_opensim.mot"  # OpenSim's shipped IK answer


def opensim_version() -> str | None:
    """The installed OpenSim's version ("4.6"), None when `opensim` is not importable."""
    try:
        import opensim
    except ImportError:
        return None
    return str(opensim.__version__)


@dataclass(frozen=True)
class IKTasks:
    """The marker tasks of an OpenSim IK setup file."""

    names: tuple[str, ...]  # markers applied, in the file's order
    weights: np.ndarray  # (n,) their weights
    time_range: tuple[float, float]  # s
    marker_file: str  # the trial, relative to the setup file


def ik_tasks(setup: str | Path = OPENSIM_DIR / IK_SETUP) -> IKTasks:
    """The IKMarkerTask entries with <apply>true</apply> of an IK setup file (xml.etree)."""
    root = ET.parse(setup).getroot()
    tool = root.find("InverseKinematicsTool")
    if tool is None:
        raise ValueError(f"{setup}: no <InverseKinematicsTool> element; not an OpenSim IK setup")
    names, weights = [], []
    for task in tool.iter("IKMarkerTask"):
        if (task.findtext("apply") or "true").strip().lower() == "true":
            names.append(task.get("name"))
            weights.append(float(task.findtext("weight") or 1.0))
    t0, t1 = (float(t) for t in (tool.findtext("time_range") or "").split())
    return IKTasks(
        tuple(names), np.asarray(weights), (t0, t1), tool.findtext("marker_file").strip()
    )


def read_trc_lab(path: str | Path) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    """(times (n,) s, marker names, positions (n, m, 3) m) of a TRC file in its own lab
    frame (no change of axes), NaN where a cell is empty: OpenSim's view of the file, for
    comparing with OpenSim's model marker locations."""
    lines = Path(path).read_text().splitlines()
    rate_keys, rate_values = lines[1].split("\t"), lines[2].split("\t")
    units = dict(zip(rate_keys, rate_values)).get("Units", "mm").strip()
    scale = {"mm": 1e-3, "m": 1.0}[units]
    names = tuple(n.strip() for n in lines[3].split("\t")[2:] if n.strip())
    rows = []
    for line in lines[5:]:
        if not line.strip():
            continue
        cells = line.split("\t")[1 : 2 + 3 * len(names)]
        rows.append([float(c) if c.strip() else np.nan for c in cells])
    data = np.asarray(rows)
    return data[:, 0], names, data[:, 1:].reshape(len(data), len(names), 3) * scale


def read_sto(path: str | Path) -> tuple[list[str], np.ndarray]:
    """(column names, data (rows, columns)) of an OpenSim .sto/.mot file."""
    lines = Path(path).read_text().splitlines()
    end = next(i for i, line in enumerate(lines) if line.strip() == "endheader")
    columns = lines[end + 1].split()
    data = np.asarray(
        [[float(x) for x in line.split()] for line in lines[end + 2 :] if line.strip()]
    )
    return columns, data


@contextlib.contextmanager
def _quiet(folder: Path):
    """OpenSim's logger off, and file descriptor 1 sent to a file: the model summary that
    loading a model prints goes to C++'s cout, past the logger's level."""
    import opensim as osim

    osim.Logger.removeFileSink()  # else it writes opensim.log into the working folder
    osim.Logger.setLevelString("error")
    import sys

    sys.stdout.flush()
    saved = os.dup(1)
    with open(folder / "stdout.txt", "w") as sink:
        os.dup2(sink.fileno(), 1)
        try:
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)


@contextlib.contextmanager
def _workdir(source: Path):
    """A temporary folder holding writable copies of `source`'s files, made the working
    folder (the setup files name their inputs relative to it)."""
    here = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="diffbody-opensim-") as tmp:
        for f in source.iterdir():
            if f.is_file():
                shutil.copyfile(f, Path(tmp) / f.name)
        os.chdir(tmp)
        try:
            yield Path(tmp)
        finally:
            os.chdir(here)


@dataclass(frozen=True)
class ScaleRun:
    seconds: float  # wall time of ScaleTool(setup) and run(), files read and written included
    ok: bool
    scale_factors: dict[str, tuple[float, float, float]]  # body -> (x, y, z) factors


def run_scale(source: Path = OPENSIM_DIR) -> ScaleRun | None:
    """OpenSim's Scale tool on the static trial (scaling by marker pairs, then marker
    placement), timed; None without OpenSim."""
    try:
        import opensim as osim
    except ImportError:
        return None
    with _workdir(source) as tmp, _quiet(tmp):
        t0 = time.perf_counter()
        tool = osim.ScaleTool(SCALE_SETUP)
        ok = bool(tool.run())
        seconds = time.perf_counter() - t0
        factors = {}
        applied = tmp / "subject01_scaleSet_applied.xml"
        if applied.exists():
            for scale in ET.parse(applied).getroot().iter("Scale"):
                xyz = tuple(float(v) for v in scale.findtext("scales").split())
                factors[scale.findtext("segment").strip()] = xyz
    return ScaleRun(seconds, ok, factors)


@dataclass(frozen=True)
class IKRun:
    seconds: float  # wall time of InverseKinematicsTool(setup) and run(), model loading included
    ok: bool
    times: np.ndarray  # (n,) s, as OpenSim writes them (rounded to 1 ms)
    rms: np.ndarray  # (n,) m, OpenSim's marker_error_RMS (unweighted, over the task markers)
    max: np.ndarray  # (n,) m, OpenSim's marker_error_max
    total_squared: np.ndarray  # (n,) m^2, OpenSim's total_squared_error (weighted)
    names: tuple[str, ...]  # task markers, in OpenSim's model order
    marker_errors: np.ndarray  # (n, m) m, |model marker - experimental marker|
    coordinates: list[str]  # the .mot's columns after time
    values: np.ndarray  # (n, k) the joint coordinates (degrees for rotations, m for translations)

    @property
    def frames(self) -> int:
        return len(self.times)


def run_ik(
    source: Path = OPENSIM_DIR, time_range: tuple[float, float] | None = None
) -> IKRun | None:
    """OpenSim's InverseKinematicsTool on the walking trial with its setup file (31 weighted
    markers, 0.4-1.6 s unless `time_range` says otherwise), timed, with OpenSim's per-frame
    marker errors and the per-marker errors of its reported model marker locations against
    the trial; None without OpenSim."""
    try:
        import opensim as osim
    except ImportError:
        return None
    with _workdir(source) as tmp, _quiet(tmp):
        t0 = time.perf_counter()
        tool = osim.InverseKinematicsTool(IK_SETUP)
        tool.set_report_errors(True)
        tool.set_report_marker_locations(True)
        tool.setResultsDir(str(tmp))
        tool.setOutputMotionFileName(str(tmp / "walk1_ik.mot"))
        if time_range is not None:
            tool.setStartTime(time_range[0])
            tool.setEndTime(time_range[1])
        ok = bool(tool.run())
        seconds = time.perf_counter() - t0
        _, errors = read_sto(tmp / f"{tool.getName()}_ik_marker_errors.sto")
        columns, located = read_sto(tmp / f"{tool.getName()}_ik_model_marker_locations.sto")
        coordinates, motion = read_sto(tmp / "walk1_ik.mot")
        trc_times, trc_names, measured = read_trc_lab(tmp / tool.getMarkerDataFileName())
    names = tuple(c[: -len("_tx")] for c in columns[1::3])
    model = located[:, 1:].reshape(len(located), len(names), 3)
    # OpenSim writes times rounded to 1 ms; the trial's frames are 1/60 s apart.
    frames = np.abs(trc_times[None, :] - located[:, :1]).argmin(1)
    measured = measured[frames][:, [trc_names.index(n) for n in names]]
    return IKRun(
        seconds=seconds,
        ok=ok,
        times=errors[:, 0],
        rms=errors[:, 2],
        max=errors[:, 3],
        total_squared=errors[:, 1],
        names=names,
        marker_errors=np.linalg.norm(model - measured, axis=-1),
        coordinates=coordinates[1:],
        values=motion[:, 1:],
    )


def ik_reference_difference(ik: IKRun, source: Path = OPENSIM_DIR) -> float:
    """The largest difference (degrees, or m for the pelvis translations) between an IK run's
    joint coordinates and OpenSim's shipped answer, frame by frame."""
    columns, shipped = read_sto(source / IK_REFERENCE)
    order = [columns.index(c) for c in ik.coordinates]
    n = min(len(shipped), len(ik.values))
    return float(np.max(np.abs(ik.values[:n] - shipped[:n][:, order])))


def ik_per_frame_seconds(source: Path = OPENSIM_DIR, repeats: int = 3) -> tuple[float, float]:
    """(median seconds of the whole IK tool over its time range, median seconds per frame of
    the solve alone): the per-frame cost is the difference between the full run and a
    one-frame run (model and trial loading, writing the files, cancel out), over the
    difference in frames."""
    tasks = ik_tasks(source / IK_SETUP)
    full, single, n = [], [], 0
    for _ in range(repeats):
        run = run_ik(source)
        one = run_ik(source, (tasks.time_range[0], tasks.time_range[0]))
        full.append(run.seconds)
        single.append(one.seconds)
        n = run.frames - one.frames
    return float(np.median(full)), float(max(np.median(full) - np.median(single), 0.0) / n)


def write_errors_csv(ik: IKRun, folder: Path) -> tuple[Path, Path]:
    """OpenSim's marker errors as two CSV files in `folder`: per frame
    (walk1_ik_marker_errors.csv: time s, rms_m, max_m) and per marker over the frames
    (walk1_ik_per_marker.csv: marker, rms_m, max_m)."""
    folder.mkdir(parents=True, exist_ok=True)
    frames, markers = folder / "walk1_ik_marker_errors.csv", folder / "walk1_ik_per_marker.csv"
    with open(frames, "w") as f:
        f.write("time,rms_m,max_m\n")
        for t, rms, worst in zip(ik.times, ik.rms, ik.max):
            f.write(f"{t:.3f},{rms:.8f},{worst:.8f}\n")
    e = ik.marker_errors
    with open(markers, "w") as f:
        f.write("marker,rms_m,max_m\n")
        for name, rms, worst in zip(ik.names, np.sqrt(np.mean(e**2, 0)), e.max(0)):
            f.write(f"{name},{rms:.8f},{worst:.8f}\n")
    return frames, markers


def main() -> None:
    """Write data/mocap/opensim/walk1_ik_{marker_errors,per_marker}.csv from a fresh
    OpenSim IK run."""
    ik = run_ik()
    if ik is None:
        raise SystemExit("opensim is not importable: pip install opensim")
    paths = write_errors_csv(ik, REPO / "data" / "mocap" / "opensim")
    print(
        f"OpenSim {opensim_version()}: {ik.frames} frames, marker RMS mean "
        f"{100 * ik.rms.mean():.2f} cm, max {100 * ik.max.max():.2f} cm; "
        f"coordinates within {ik_reference_difference(ik):.3f} of the shipped answer; "
        f"wrote {', '.join(str(p.relative_to(REPO)) for p in paths)}"
    )


if __name__ == "__main__":
    main()
