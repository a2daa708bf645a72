"""The summary of a folder of trials (`fit_trials`' `trials.csv`): its header, which says
what produced the file, and the check a resumed run makes against it (docs/design.md,
section 7)."""

from pathlib import Path

import numpy as np

from ..runs._header import BODY_KEYS, body_fields, file_sha256, header_changes
from ..runs._streaming import tree_hash

FORMAT = "diffbody.mocap-trials/1"  # the summary CSV's layout, its first header line
SUMMARY = "trials.csv"
COLUMNS = ["trial", "sha256", "frames", "markers", "status", "converged", "marker_rms_m", "notes"]
# The settings a resumed run must share with the run that began the file, as a change of
# each is told.
SETTINGS = {
    "keep-zeros": "--keep-zeros",
    "axes": "--axes",
    "prior": "the prior (--no-prior)",
    "measured": "the readings (--measure, --measure-sd)",
    "motion-frames": "the registration's frames of the trials (--motion-frames)",
    "velocity": "the motion fits' velocity term (--no-velocity)",
    "time": "--time",
    "opensim-model": "--opensim-model",
    "float": "the float precision (JAX_ENABLE_X64)",
}


def header_fields(
    body,
    static,
    markerset,
    tasks,
    *,
    keep_zeros,
    axes,
    prior,
    time,
    readings=None,
    motion_frames=0,
    velocity=True,
):
    """The summary CSV's header, in the order written. `--resume` checks all but the file
    names (`static`, `tasks`: their hashes are checked) and `begun` (UTC)."""
    from datetime import datetime, timezone

    import jax.numpy as jnp

    names = "\n".join([markerset.name, *markerset.names, *markerset.kinds])
    layout = np.frombuffer(names.encode(), np.uint8), np.asarray(markerset.segments)
    return [
        ("format", FORMAT),
        ("static", str(static)),
        ("static-sha256", file_sha256(static)),
        *body_fields(body),
        ("markerset", markerset.name),
        ("markerset-hash", tree_hash((layout, markerset))),
        ("tasks", str(tasks) if tasks else "(none)"),
        ("tasks-sha256", file_sha256(tasks) if tasks else "(none)"),
        ("keep-zeros", "on" if keep_zeros else "off"),
        ("axes", axes or "(each file's own)"),
        ("prior", "on" if prior else "off"),
        ("measured", readings_field(readings or {})),
        ("motion-frames", str(motion_frames)),
        ("velocity", "on" if velocity else "off"),
        ("time", f"{time[0]!r} {time[1]!r}" if time is not None else "(all)"),
        ("float", jnp.dtype(jnp.result_type(float)).name),  # JAX_ENABLE_X64 changes the fits
        ("begun", datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")),
    ]


def readings_field(readings: dict) -> str:
    """The readings (`scale_and_register`'s measured, measured_sd) in the header."""
    from ._tape_readings import TAPE_SD

    if not readings:
        return "(none)"
    sd = readings.get("measured_sd", TAPE_SD)
    values = " ".join(f"{n}={float(v)!r}" for n, v in sorted(readings["measured"].items()))
    return f"{values} sd={sd!r}"


def summary_changes(old: dict[str, str], new: dict[str, str]) -> list[str]:
    """What differs between a summary's header (`old`) and this run's (`new`), in words."""
    # A summary begun before readings or the registration's frames were recorded was begun
    # without readings, on the static trial alone.
    # Summaries from before a setting existed were fitted as its absence: no readings, the
    # static trial alone, no velocity term.
    old = {"measured": "(none)", "motion-frames": "0", "velocity": "off", **old}
    changes = header_changes(old, new, {"static-sha256": "the static trial"}, SETTINGS)
    body_changed = any(old.get(k) != new[k] for k in BODY_KEYS)
    # The set is resolved on the body: another body moves its offsets, and that is told.
    if old.get("markerset") != new["markerset"] or (
        old.get("markerset-hash") != new["markerset-hash"] and not body_changed
    ):
        changes.append(
            f"the marker set changed ({old.get('markerset')} {old.get('markerset-hash')} vs "
            f"{new['markerset']} {new['markerset-hash']})"
        )
    if old.get("tasks-sha256") != new["tasks-sha256"]:

        def sha(h):
            return h.get("tasks-sha256", "(not recorded)")[:16]

        changes.append(
            f"--tasks changed from {old.get('tasks', '(not recorded)')} (sha256 {sha(old)}) "
            f"to {new['tasks']} (sha256 {sha(new)})"
        )
    return changes


def recorded_rows(path: Path, fields, shas: dict[str, str | None]):
    """The summary's header text and its whole rows (line, cells) after checking them
    against this run; a difference is refused, naming it. Writes nothing."""
    from ..runs._streaming import read_results, read_rows

    have = read_results(str(path))
    refuse = "rerun as it was begun, or without --resume to start over"
    if have.fields.get("format") != FORMAT or have.columns != COLUMNS:
        raise ValueError(
            f"--resume {path.parent}: {path} is not a summary of format {FORMAT} with columns "
            f"{','.join(COLUMNS)}; rerun without --resume to start over"
        )
    header, rows = read_rows(have)
    for number, (_, cells) in enumerate(rows, start=1):
        if len(cells) != len(COLUMNS):
            raise ValueError(
                f"--resume {path.parent}: {path}: trial row {number} has {len(cells)} cells, "
                f"not {len(COLUMNS)} (the file was edited); rerun without --resume to start over"
            )
    changes = summary_changes(have.fields, dict(fields))
    for _, cells in rows:
        name, sha = cells[0], cells[1] if len(cells) > 1 else ""
        if name not in shas:
            changes.append(f"the trial {name} is recorded but is not among the trials now")
        elif shas[name] != sha:
            now = (shas[name] or "(unreadable)")[:16]
            changes.append(f"the trial {name} changed (sha256 {sha[:16]}... vs {now}...)")
    if changes:
        raise ValueError(f"--resume {path.parent}: {'; '.join(changes)}; {refuse}")
    return header, rows, have.ends[-1] if have.ends else have.start
