"""What a motion-capture fit writes (`diffbody mocap`, one trial or a folder of them): the
pose file of a fit, the scaled body, OpenSim's coordinates (.mot), the ISB joint angles
(.angles.mot), the model's markers (.trc) and pictures. Each file is written whole or not
at all: first under a temporary folder beside it (`NAME.EXT.partial/NAME.EXT`, so that a
writer that puts the file's name inside it puts the right one), flushed to the disk, then
moved over the file (`os.replace`)."""

import dataclasses
import json
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..runs._streaming import fsync_file, replace_atomically

PICTURE_FRAMES = 4  # frames drawn in the PNG, evenly over the trial
PARTIAL = ".partial"  # what the name of a file or folder being written carries
# The optional outputs of each trial: the option, and what follows NAME in the file name.
OUTPUTS = {
    "mot": ".mot",
    "angles": ".angles.mot",
    "trc": ".model.trc",
    "png": ".png",
    "curves": ".curves.png",
}
# The OpenSim model whose coordinates a .mot holds when none is named: gait2354, its frames
# placed through its Scale marker set (`model_frames`).
DEFAULT_MODEL = "mocap/gait2354_Scale_MarkerSet.xml"


def load_any_markerset(name_or_path: str, body):
    """A shipped or JSON marker set (`load_markerset`), or an OpenSim one (.xml, .osim:
    `load_opensim_markerset`)."""
    if str(name_or_path).lower().endswith((".xml", ".osim")):
        from ..files._opensim_files import load_opensim_markerset

        return load_opensim_markerset(name_or_path, body)
    from ..files._markerset_file import load_markerset

    return load_markerset(name_or_path, body)


@contextmanager
def written_whole(path: str | Path) -> Iterator[Path]:
    """The name to write `path` under: a file in a temporary folder beside it, which
    replaces `path` (after an fsync) when the block ends; an error in the block leaves
    `path` as it was and removes the temporary."""
    path = Path(path)
    folder = path.with_name(path.name + PARTIAL)
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    tmp = folder / path.name
    try:
        yield tmp
        fsync_file(str(tmp))
        os.replace(tmp, path)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def remove_partials(folder: str | Path) -> list[str]:
    """Remove what a killed run left half-written in `folder` (the names with `.partial`);
    the names removed."""
    removed = []
    folder = Path(folder)
    if not folder.is_dir():
        return removed
    for entry in sorted(folder.iterdir()):
        if PARTIAL in entry.name:
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
            removed.append(entry.name)
    return removed


def scaled_body(static_fit, body):
    """The static fit's scaled body, named after the body it was scaled from."""
    return dataclasses.replace(static_fit.body, name=f"{body.name}-mocap")


def save_scaled_body(body, path: str | Path) -> Path:
    """`save_body`'s files (a body with a spine gets `<stem>.spine.json` beside it), each
    written whole."""
    from ..files._saving import body_document, spine_document

    path = Path(path)
    spine_file = None
    if body.spine is not None:
        spine_file = f"{path.stem}.spine.json"
        text = json.dumps(spine_document(body.spine), indent=1)
        replace_atomically(str(path.parent / spine_file), text)
    replace_atomically(str(path), json.dumps(body_document(body, spine_file), indent=1))
    return path


def save_fit(path: str | Path, scaled, static_fit, fit, trial) -> Path:
    """A motion fit as a pose file (.npz), written whole: the scaled body's poses, times,
    statuses, per-frame residuals, the measured markers as overlays, the model markers."""
    from .._solver import FitStatus
    from ..anthropometry._scaling import SCALE_GROUPS
    from ..files._pose_file import save_pose

    per_marker = fit.per_marker()
    with written_whole(path) as tmp:
        save_pose(
            tmp,
            scaled,
            fit.poses,
            times=fit.times,
            status=[FitStatus(int(s)).name.lower() for s in np.asarray(fit.status)],
            residuals={
                "rms": fit.rms,  # (n_frames,) m over the markers
                "max": fit.max,
                "errors": fit.errors,  # (n_frames, n_markers) m, NaN where missing
                "outliers": fit.outliers,  # (n_frames, n_markers) beyond the robust scale
            },
            scale={"groups": list(SCALE_GROUPS), "axial": static_fit.axial},
            overlays={"markers": {"names": list(fit.names), "positions": trial.positions}},
            extra={
                "marker_kinds": list(fit.kinds),
                "model_markers": fit.markers,  # (n_frames, n_markers, 3) m, world
                "marker_rms": [per_marker[n][0] for n in fit.names],
                "marker_max": [per_marker[n][1] for n in fit.names],
                "static_marker_names": list(static_fit.markerset.names),
                "static_errors": static_fit.errors,
            },
        )
    return Path(path)


def save_angles(path: str | Path, fit, scaled, name: str) -> Path:
    """The ISB joint angles of every frame (`joint_angles`: ISB's names and signs), degrees,
    as a .mot file, written whole."""
    from ..files._motion_files import write_mot

    with written_whole(path) as tmp:
        write_mot(tmp, fit.times, fit.angles(scaled), name=name)
    return Path(path)


def save_coordinates(path: str | Path, fit, static_fit, scaled, name: str, model=None) -> Path:
    """OpenSim's coordinates of every frame (`opensim_coordinates`) for `model` (an .osim or
    an OpenSim marker set .xml; None: gait2354's), as a .mot that drives that model, written
    whole. Its frames are placed through the model's markers and the static fit's."""
    from ..files._data_files import data_file
    from ..files._motion_files import write_mot
    from ..files._opensim_files import read_model_markers
    from ._model_frames import model_frames

    markers = read_model_markers(data_file(DEFAULT_MODEL) if model is None else model)
    frames = model_frames(static_fit.body, static_fit.markerset, markers)
    with written_whole(path) as tmp:
        write_mot(tmp, fit.times, fit.coordinates(scaled, frames), name=name)
    return Path(path)


def save_model_markers(path: str | Path, fit, trial, axes: str) -> Path:
    """The model's markers of every frame as a TRC file in the lab axes `axes`."""
    from ..files._marker_trial import MarkerTrial
    from ..files._trc import write_trc

    model = MarkerTrial(fit.names, fit.times, fit.markers, trial.rate, str(path))
    with written_whole(path) as tmp:
        write_trc(tmp, model, axes=axes)
    return Path(path)


def save_curves(path: str | Path, fit, scaled, title: str) -> Path:
    """The fit over time (`draw_motion`) as a PNG, written whole."""
    from ._motion_plots import draw_motion

    with written_whole(path) as tmp:
        draw_motion(fit, scaled, title=title, path=tmp)
    return Path(path)


def draw_markers(ax, points, view="left", **style) -> None:
    """Scatter world points (n, 3) m over a `diffbody.draw`n body, in the same projection;
    NaN rows (missing markers) are skipped."""
    from .._render import camera

    points = np.asarray(points, float)
    points = points[np.all(np.isfinite(points), axis=1)]
    _, right, up, _ = camera(view)
    ax.scatter(points @ right, points @ up, zorder=5, **style)


def picture(body, fit, measured, path, title: str, view="left") -> Path:
    """A PNG of a few frames of a motion fit, written whole: the sphere body, the measured
    markers (blue rings) and the model's (red dots)."""
    import jax
    import jax.numpy as jnp
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from .._render import draw

    n = len(fit.times)
    frames = np.unique(np.linspace(0, n - 1, min(PICTURE_FRAMES, n)).round().astype(int))
    fig, axes = plt.subplots(1, len(frames), figsize=(3.0 * len(frames), 5.0), squeeze=False)
    for ax, i in zip(axes[0], frames):
        pose = jax.tree.map(lambda a: jnp.asarray(a[i]), fit.poses)
        draw(ax, body, pose, view)
        draw_markers(ax, measured[i], view, s=28, facecolors="none", edgecolors="tab:blue", lw=1)
        draw_markers(ax, fit.markers[i], view, s=6, color="crimson")
        ax.set_title(
            f"t = {float(fit.times[i]):.2f} s, RMS {100 * float(fit.rms[i]):.1f} cm", fontsize=9
        )
    # One scale for every panel: the widest panel's width, the tallest one's height.
    width = max(np.diff(ax.get_xlim())[0] for ax in axes[0])
    top = max(ax.get_ylim()[1] for ax in axes[0])
    for ax in axes[0]:
        middle = np.mean(ax.get_xlim())
        ax.set_xlim(middle - width / 2, middle + width / 2)
        ax.set_ylim(min(ax.get_ylim()[0], -0.05), top)
    fig.suptitle(f"diffbody mocap: {title} (measured markers: rings; model: dots)", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    with written_whole(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return path


def trial_outputs(out_dir: Path, name: str, options) -> list[Path]:
    """The files a trial's fit writes into `out_dir`: the pose file, then each of
    `options` (names of `OUTPUTS`)."""
    return [out_dir / f"{name}.npz"] + [out_dir / f"{name}{OUTPUTS[o]}" for o in options]


def trial_cells(fit) -> list[str]:
    """A fitted trial's row after its name and sha256: frames, markers, status, frames
    converged, the inliers' marker RMS (m) and the faulty markers."""
    from .._solver import FitStatus

    status = np.asarray(fit.status)
    converged = int(np.sum(status == FitStatus.CONVERGED))
    if np.any(status == FitStatus.FAILED):
        word = "failed"
    else:
        word = "converged" if converged == len(status) else "not_converged"
    notes = "; ".join(f"{name}: {why}" for name, why in fit.flagged().items())
    rms = f"{fit.summary()['inlier_rms']:.9g}"
    return [str(len(fit.times)), str(len(fit.names)), word, str(converged), rms, notes]


def write_trial_files(
    out_dir, path, fit, trial, static_fit, scaled, outputs, axes, model=None
) -> None:
    """A fitted trial's files, each written whole (`model`: the OpenSim model of the .mot)."""
    name = path.stem
    save_fit(out_dir / f"{name}.npz", scaled, static_fit, fit, trial)
    if "mot" in outputs:
        save_coordinates(
            out_dir / f"{name}.mot", fit, static_fit, scaled, f"{name} OpenSim coordinates", model
        )
    if "angles" in outputs:
        save_angles(out_dir / f"{name}.angles.mot", fit, scaled, name=f"{name} ISB angles")
    if "trc" in outputs:
        save_model_markers(out_dir / f"{name}.model.trc", fit, trial, axes or "opensim")
    if "png" in outputs:
        picture(scaled, fit, trial.positions, out_dir / f"{name}.png", path.name)
    if "curves" in outputs:
        save_curves(out_dir / f"{name}.curves.png", fit, scaled, title=path.name)
