"""A folder of motion-capture trials fitted against one static registration (`fit_trials`;
the command: `diffbody mocap STATIC TRIALS_DIR/`), streamed and resumable.

The body is scaled and registered once, on the static trial and frames spread over every
trial (`scale_and_register(motion=)`); every trial is then fitted in
turn, and its files are written into the output folder as soon as it finishes, each whole
or not at all (`_trial_outputs.written_whole`): `NAME.npz` (the fit's pose file), and on
request `NAME.mot`, `NAME.model.trc`, `NAME.png`, `NAME.curves.png`; the scaled body once
(`body.json`). Then the trial's row is appended to `trials.csv` (diffbody.runs._streaming's
layout: `#` header lines that say what produced the file, the column names, one row per
finished trial, each appended in one write and fsynced). No timings go into the file: two
runs give the same bytes but for the `# begun:` line.

`resume=True` checks the file's header against the run asked for (the static trial's
sha256, the body, the marker set, the settings that change the fits) and each recorded
trial's sha256, and refuses a difference, naming it; it then skips the recorded trials whose
files are there and fits the rest. A trial that cannot be read or fitted is a row with
status `error` and the reason; the others go on.
"""

import csv
import glob
import io
import os
import time as clock
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..runs._header import file_sha256
from ..runs._streaming import (
    Interrupts,
    append_lines,
    header_text,
    replace_atomically,
    truncate,
)
from ._grades import grade_motion, grade_static, readings_report, registration_report
from ._motion_registration import MOTION_FRAMES
from ._trial_outputs import (
    OUTPUTS,
    load_any_markerset,
    remove_partials,
    save_scaled_body,
    scaled_body,
    trial_cells,
    trial_outputs,
    write_trial_files,
)
from ._trials_summary import COLUMNS, SUMMARY, header_fields, recorded_rows

BODY_FILE = "body.json"
TRIAL_SUFFIXES = (".trc", ".c3d")


@dataclass(frozen=True)
class TrialsSummary:
    """What `fit_trials` did: `fitted`, the trials fitted by this run (file names, in
    order); `resumed`, those an earlier run had done (skipped); `failed`, those of either
    whose status is `failed` or `error`; `summary`, the CSV (`out_dir/trials.csv`)."""

    out_dir: Path
    summary: Path
    total: int
    fitted: tuple[str, ...]
    resumed: tuple[str, ...]
    failed: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.failed


def trial_files(trials) -> list[Path]:
    """The trial files that `trials` names: a list of files as given; a folder: its .trc
    and .c3d files; a glob pattern ('trials/*.trc'): the files it matches; else one file.
    Sorted by file name (a folder, a pattern)."""
    if isinstance(trials, (list, tuple)):
        return [Path(p) for p in trials]
    path = Path(trials)
    if path.is_dir():
        found = [p for p in path.iterdir() if p.is_file() and p.suffix.lower() in TRIAL_SUFFIXES]
        if not found:
            raise ValueError(f"{trials}: no .trc or .c3d file in this folder")
    elif glob.has_magic(str(trials)) and not path.exists():
        found = [Path(p) for p in glob.glob(str(trials), recursive=True) if Path(p).is_file()]
        if not found:
            raise ValueError(f"{trials}: no file matches this pattern")
    else:
        return [path]
    return sorted(found, key=lambda p: (p.name, str(p)))


def noted(log, fn, *args, **kwargs):
    """fn's result; its warnings (markers one file has and the other lacks) told through
    `log` as notes, one line each, instead of Python's warning format."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = fn(*args, **kwargs)
    for w in caught:
        log(f"note: {w.message}")
    return out


def _why(e: Exception) -> str:
    """An error's message on one line, as the command line words it."""
    if isinstance(e, KeyError) and e.args:
        text = str(e.args[0])
    elif isinstance(e, OSError) and e.filename and e.strerror:
        text = f"{e.filename}: {e.strerror}"
    else:
        text = str(e) or type(e).__name__
    return " ".join(text.split())


def _row(cells) -> str:
    text = io.StringIO()
    csv.writer(text, lineterminator="\n").writerow(cells)
    return text.getvalue()


def fit_trials(
    body,
    static,
    trials,
    markerset="opensim-gait",
    out_dir="fits",
    *,
    resume: bool = False,
    tasks=None,
    keep_zeros: bool = False,
    axes: str | None = None,
    prior: bool = True,
    readings: dict | None = None,
    motion_frames: int = MOTION_FRAMES,
    velocity: bool = True,
    time: tuple[float, float] | None = None,
    outputs=(),
    opensim_model=None,
    progress: bool = False,
    log=print,
    signals=None,
) -> TrialsSummary:
    """Scale and register `body` on the `static` trial (and `motion_frames` frames spread
    over the trials) once, then fit every trial against it, writing each trial's files and
    its summary row as it finishes (module docstring).

    Args:
        body: the template body; static: the static trial's file (.trc or .c3d).
        trials: a folder, a glob pattern or a list of trial files (`trial_files`).
        markerset: a shipped name, a JSON or OpenSim (.xml, .osim) file, or a `MarkerSet`
            resolved for `body`.
        out_dir: the output folder (made if missing).
        resume: go on with an interrupted run's `out_dir` (module docstring); else a
            `trials.csv` there is begun anew.
        tasks: an OpenSim IK task-set or set-up file (`read_ik_tasks`): the markers and
            weights of the motion fits.
        keep_zeros, axes: how the marker files are read (`read_markers`: `zero_is_gap` is
            `not keep_zeros`); prior: `scale_and_register`'s; readings: its readings as
            keyword arguments ({"measured": {...}, "measured_sd": ...}; None: none);
            motion_frames: the frames of the trials the registration fits as well, spread
            over every trial that can be read (`scale_and_register`'s; 0: the static trial
            alone); velocity: `fit_motion`'s velocity term (False: off); time: (t0, t1) s,
            the frames of each trial fitted.
        outputs: the optional files of each trial, names of `OUTPUTS` ("mot", "angles",
            "trc", "png", "curves").
        opensim_model: the OpenSim model each .mot drives (`save_coordinates`; None:
            gait2354).
        progress: a progress bar per trial on stderr; log: where the report lines go.
        signals: an entered `diffbody.runs._streaming.Interrupts`, or None for one of its own.
            A signal stops the run between two trials' writes with `Interrupted`: the
            finished trials are in `out_dir`, and `resume=True` goes on from there.

    Returns:
        A `TrialsSummary`. A trial that cannot be read or fitted is recorded (status
        `error`, the reason in `notes`), told to `log` as `TRIAL: skipped: WHY`, and the
        run goes on.
    """
    arguments = dict(locals())
    if signals is None:
        with Interrupts() as own:
            return fit_trials(**{**arguments, "signals": own})
    from ..files._marker_files import read_markers
    from ..files._opensim_files import read_ik_tasks

    unknown = [o for o in outputs if o not in OUTPUTS]
    if unknown:
        raise ValueError(f"fit_trials: unknown outputs {unknown}; use some of {list(OUTPUTS)}")
    outputs = [o for o in OUTPUTS if o in outputs]
    paths, out_dir = trial_files(trials), Path(out_dir)
    names = [p.stem for p in paths]
    for name in sorted({n for n in names if names.count(n) > 1}):
        same = [str(p) for p in paths if p.stem == name]
        raise ValueError(f"trials {' and '.join(same)} would both write {name}.npz; rename one")
    for p in paths:
        if out_dir.is_dir() and p.parent.resolve() == out_dir.resolve():
            raise ValueError(f"{out_dir}: holds the trial {p.name}; give another output folder")
    # The files before the solves: a malformed static trial is told in milliseconds.
    zero_is_gap = not keep_zeros
    static_trial = read_markers(static, axes=axes, zero_is_gap=zero_is_gap)
    weights_of = read_ik_tasks(tasks) if tasks else None
    if isinstance(markerset, (str, os.PathLike)):
        markerset = noted(log, load_any_markerset, str(markerset), body)
    fields = header_fields(
        body,
        static,
        markerset,
        tasks,
        keep_zeros=keep_zeros,
        axes=axes,
        prior=prior,
        time=time,
        readings=readings,
        motion_frames=motion_frames,
        velocity=velocity,
    )
    fields.insert(-1, ("opensim-model", str(opensim_model) if opensim_model else "gait2354"))
    shas = {}
    for p in paths:
        try:
            shas[p.name] = file_sha256(p)
        except OSError:
            shas[p.name] = None
    summary = out_dir / SUMMARY
    kept = []
    if resume and summary.exists():
        header, rows, end = recorded_rows(summary, fields, shas)
    elif resume:
        log(f"--resume: no {summary} yet; starting from the first trial")
    with signals.held():
        out_dir.mkdir(parents=True, exist_ok=True)
        remove_partials(out_dir)
        if resume and summary.exists():
            kept = [
                (line, cells)
                for line, cells in rows
                if cells[4] == "error"
                or all(f.exists() for f in trial_outputs(out_dir, Path(cells[0]).stem, outputs))
            ]
            if len(kept) == len(rows):
                truncate(str(summary), end)  # a partial last line, left by a kill, goes
            else:  # a trial whose files are gone is fitted again
                replace_atomically(str(summary), header.decode() + "".join(ln for ln, _ in kept))
            log(f"resuming {out_dir} after {len(kept)} of {len(paths)} trials")
        else:
            replace_atomically(str(summary), header_text(fields, COLUMNS))
    done = {cells[0] for _, cells in kept}
    failed = [cells[0] for _, cells in kept if cells[4] in ("failed", "error")]
    todo = [p for p in paths if p.name not in done]
    body_files = [out_dir / BODY_FILE]
    fitted = []
    if todo or not body_files[0].exists():
        t0 = clock.perf_counter()
        from ._static_fit import scale_and_register

        # Every readable trial, not the ones left to fit: a resumed run registers as the
        # run that began the folder did.
        motion = [m for m in (_read(p, axes, zero_is_gap, time) for p in paths) if m is not None]
        settings = dict(prior=prior, motion=motion or None, motion_frames=motion_frames)
        static_fit = noted(
            log, scale_and_register, body, static_trial, markerset, **settings, **(readings or {})
        )
        scaled = scaled_body(static_fit, body)
        with signals.held():
            save_scaled_body(scaled, body_files[0])
        rms = float(np.sqrt(np.mean(np.asarray(static_fit.errors) ** 2)))
        log(
            f"{static}: {len(static_trial.names)} markers; scaled and registered in "
            f"{clock.perf_counter() - t0:.1f} s, marker RMS {100 * rms:.2f} cm; "
            f"wrote {body_files[0]}"
        )
        if registration_report(static_fit):
            log(registration_report(static_fit))
        if readings:
            log(readings_report(static_fit.body, readings["measured"]))
        for grade in grade_static(static_fit):  # OpenSim's best practices
            log(f"  {grade.line()}")
    for path in todo:
        t0 = clock.perf_counter()
        cells = [path.name, shas[path.name] or "", "", "", "error", "", "", ""]
        try:
            fit, trial = _fit_one(
                path,
                static_fit,
                weights_of,
                tasks,
                time,
                axes,
                zero_is_gap,
                velocity,
                progress,
                log,
            )
        except Exception as e:  # the trial's error is its row; the others go on
            cells[-1] = _why(e)
            log(f"{path}: skipped: {cells[-1]}")
            with signals.held():
                append_lines(str(summary), _row(cells))
            failed.append(path.name)
            continue
        cells[2:] = trial_cells(fit)
        with signals.held():  # the trial's files, then its row: a row has its files
            write_trial_files(
                out_dir, path, fit, trial, static_fit, scaled, outputs, axes, opensim_model
            )
            append_lines(str(summary), _row(cells))
        fitted.append(path.name)
        if cells[4] == "failed":
            failed.append(path.name)
        log(
            f"{path.name}: {cells[2]} frames, {cells[3]} markers, {cells[5]} of {cells[2]} "
            f"frames converged, marker RMS {100 * float(cells[6]):.2f} cm over the inliers "
            f"({clock.perf_counter() - t0:.1f} s); faulty markers: {cells[7] or 'none'}"
        )
        for grade in grade_motion(fit):
            log(f"  {grade.line()}")
    return TrialsSummary(
        out_dir=out_dir,
        summary=summary,
        total=len(paths),
        fitted=tuple(fitted),
        resumed=tuple(sorted(done, key=[p.name for p in paths].index)),
        failed=tuple(n for n in (p.name for p in paths) if n in failed),
    )


def _trial(path, axes, zero_is_gap, time):
    """A trial's markers within `time` (s; None: every frame). Raises what reading it
    raises, and ValueError for no frame within `time`."""
    from ..files._marker_files import read_markers

    motion = read_markers(path, axes=axes, zero_is_gap=zero_is_gap)
    if time is not None:
        whole, motion = motion, motion.between(*time)
        if len(motion.times) == 0:
            raise ValueError(
                f"--time {time[0]:g} {time[1]:g}: no frame of {path} in that range; its "
                f"frames run {whole.times[0]:.3f}-{whole.times[-1]:.3f} s"
            )
    return motion


def _read(path, axes, zero_is_gap, time):
    """`_trial` for the registration: None where it raises (the trial's own fit tells why)."""
    try:
        return _trial(path, axes, zero_is_gap, time)
    except (OSError, ValueError, KeyError):
        return None


def _fit_one(path, static_fit, weights_of, tasks, time, axes, zero_is_gap, velocity, progress, log):
    """One trial's `MotionFit` and its trial (the markers matched to the set)."""
    from ._markerset import match_markers
    from ._motion_fit import fit_motion

    motion = _trial(path, axes, zero_is_gap, time)
    registered, trial = noted(log, match_markers, static_fit.markerset, motion)
    weights = None
    if weights_of is not None:
        unused = [n for n in weights_of if n not in registered.names]
        if unused:
            log(f"note: {tasks}: tasks for markers the fit lacks, ignored: {', '.join(unused)}")
        weights = {n: w for n, w in weights_of.items() if n in registered.names}
    fit = noted(
        log,
        fit_motion,
        static_fit.body,
        registered,
        trial,
        start=static_fit.pose,
        weights=weights,
        scale=static_fit.marker_scale,
        velocity=velocity,
        progress=progress,
    )
    return fit, trial
