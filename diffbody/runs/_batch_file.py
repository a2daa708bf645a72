"""The results of a streamed reach batch (`run_reach_batch`, `diffbody batch`):
a CSV appended a chunk at a time, its postures as one pose file per chunk until the run is
complete, then merged (docs/design.md, section 6).

    results.csv                 # key: value header lines, column names, one row per target
    results.poses/part-00000.npz   one pose file per finished chunk, while the run goes on
    results.poses.npz           all the postures, once every chunk is done

With several processes each writes its share of the rows to a part of the CSV
(results.process-1-of-2.csv, its rows numbered as in the whole), and the postures of its
chunks to the shared folder; process 0 merges both at the end. The header is what
`--resume` checks: a run goes on with a file only when the input, the body and every
setting that changes a row are the same.
"""

import csv
import io
import os
import re
from datetime import datetime, timezone

import jax
import numpy as np

from .._statuses import ReachStatus
from ._header import body_fields, header_changes
from ._streaming import read_results, tree_hash, truncate

FORMAT = "diffbody.batch/1"  # the results CSV's layout, its first header line

# What each setting in the header is called where it was given, for the refusals' wording:
# the Python keywords (the command line passes its option names).
KEYWORDS = {
    "effectors": "effectors",
    "segments": "segments=",
    "spine": "spine=",
    "starts": "starts=",
    "chunk-size": "chunk_size=",
    "standing": "standing=",
    "constraints": "constraints=",
    "start-pose": "init=",
    "max-steps": "max_steps=",
    "tol-position": "tol_position=",
    "float": "the float precision (JAX_ENABLE_X64)",
}


def poses_path(out: str) -> str:
    """The postures file beside a results CSV: results.csv -> results.poses.npz."""
    return f"{os.path.splitext(out)[0]}.poses.npz"


def parts_path(out: str) -> str:
    """The folder of a run's postures, one pose file per finished chunk, until the run is
    complete: results.csv -> results.poses/."""
    return f"{os.path.splitext(out)[0]}.poses"


def part_path(parts: str, index: int) -> str:
    """Chunk `index`'s pose file in the folder of parts."""
    return os.path.join(parts, f"part-{index:05d}.npz")


def process_path(out: str, process: int, count: int) -> str:
    """Where process `process` of `count` writes its rows: `out` itself for one process,
    else results.csv -> results.process-1-of-2.csv."""
    if count == 1:
        return out
    root, ext = os.path.splitext(out)
    return f"{root}.process-{process}-of-{count}{ext}"


def header_fields(
    input: str, sha256: str, total: int, body, effectors, chunk: int, settings: dict
) -> list[tuple[str, str]]:
    """The results CSV's header: what produced it, in the order written: the input (its name,
    hash and rows), the body, the effectors, the chunk size and `settings` (the solve's
    `segments`, `spine`, `starts`, `standing`, `constraints`, `init`, `max_steps`,
    `tol_position`). `--resume` checks all but `input` (the file may move; its hash is
    checked), `rows` (follows from the hash) and `begun` (the time the file was begun, UTC)."""
    s = settings
    return [
        ("format", FORMAT),
        ("input", input),
        ("input-sha256", sha256),
        ("rows", str(total)),
        *body_fields(body),
        ("effectors", " ".join(effectors)),
        ("segments", " ".join(s["segments"]) if s["segments"] else "(all)"),
        ("spine", "on" if s["spine"] else "off"),
        ("starts", str(s["starts"])),
        ("chunk-size", str(chunk)),
        ("standing", "on" if s["standing"] else "off"),
        ("constraints", f"{len(s['constraints'])} ({tree_hash(list(s['constraints']))})"),
        ("start-pose", "standard position" if s["init"] is None else tree_hash(s["init"])),
        ("max-steps", str(s["max_steps"])),
        ("tol-position", f"{s['tol_position']:g}"),
        ("float", np.dtype(jax.numpy.result_type(float)).name),  # JAX_ENABLE_X64 changes rows
        ("begun", datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")),
    ]


def columns(effectors) -> list[str]:
    """The results CSV's column names."""
    names = ["row"]
    for e in effectors:
        names += [f"{e}.residual", f"{e}.reached", f"{e}.valid"]
    return names + ["status", "steps"]


def status_names(status) -> list[str]:
    """ReachStatus codes as the CSV and pose files name them."""
    return [ReachStatus(int(s)).name.lower() for s in status]


def rows_text(result, at: int) -> str:
    """A chunk's result rows as CSV lines, numbered from `at`."""
    text = io.StringIO()
    w = csv.writer(text, lineterminator="\n")
    k = result.residuals.shape[1]
    for i, status in enumerate(status_names(result.status)):
        cells = [at + i]
        for j in range(k):
            cells += [
                f"{float(result.residuals[i, j]):.9g}",
                int(result.reached[i, j]),
                int(result.valid[i, j]),
            ]
        w.writerow(cells + [status, int(result.steps[i])])
    return text.getvalue()


def rows_reached(out: str, effectors) -> int:
    """The rows of a results CSV whose every effector reached its target."""
    with open(out, newline="", encoding="utf-8") as f:
        rows = csv.DictReader(line for line in f if not line.startswith("#"))
        return sum(all(row[f"{e}.reached"] == "1" for e in effectors) for row in rows)


def check_header(have, fields, names, out: str, resume_option: str) -> None:
    """Refuse to go on with results `have` (`read_results`) begun by another run, naming
    what changed."""
    if have.fields.get("format") != FORMAT:
        found = have.fields.get("format")
        raise ValueError(
            f"{resume_option} {out}: not a `diffbody batch` file of format {FORMAT} (its header "
            f"{'says ' + repr(found) if found else 'is missing'}); start over without "
            f"{resume_option}"
        )
    told = header_changes(have.fields, dict(fields), {"input-sha256": "the input file"}, names)
    if told:
        raise ValueError(
            f"{resume_option} {out}: {'; '.join(told)}; rerun as it was begun, or without "
            f"{resume_option} to start over"
        )


def is_complete(out: str, total: int) -> bool:
    """Whether `out` holds a finished run: every row and the merged postures."""
    if not (os.path.exists(out) and os.path.exists(poses_path(out))):
        return False
    if os.path.exists(parts_path(out)):
        return False
    return len(read_results(out).ends) == total


def resume_point(
    path: str, fields, names, share: range, chunk: int, total: int, resume_option: str
) -> int:
    """The rows of this process's share (chunks `share`) that an interrupted run left whole
    in `path`, with their postures in the folder of parts. Cuts the file back to them and
    removes the parts of later chunks of the share. A header that differs from this run's
    is refused, naming what changed."""
    have = read_results(path)
    check_header(have, fields, names, path, resume_option)
    expected = columns(fields_effectors(fields))
    if have.columns != expected:
        raise ValueError(
            f"{resume_option} {path}: its columns are {','.join(have.columns)}, not "
            f"{','.join(expected)}; start over without {resume_option}"
        )
    first = share.start * chunk
    for i, cell in enumerate(have.first_cells):
        if cell != str(first + i):
            raise ValueError(
                f"{resume_option} {path}: result row {i + 1} is numbered {cell!r}, not "
                f"{first + i} (the file was edited); start over without {resume_option}"
            )
    size = min(share.stop * chunk, total) - first
    rows = min(len(have.ends), size)
    whole = len(share) if rows == size else rows // chunk
    parts = parts_path(out_of(path))
    present = 0
    while present < whole and os.path.exists(part_path(parts, share.start + present)):
        present += 1
    keep = min(present * chunk, size)
    truncate(path, have.ends[keep - 1] if keep else have.start)
    remove_parts(parts, range(share.start + present, share.stop))
    return keep


def fields_effectors(fields) -> list[str]:
    return dict(fields)["effectors"].split(" ")


def out_of(path: str) -> str:
    """The results CSV a process's part belongs to (itself for one process)."""
    return re.sub(r"\.process-\d+-of-\d+(\.[^.]*)?$", r"\1", path)


def remove_file(path: str) -> None:
    if os.path.exists(path):
        os.remove(path)


def remove_parts(parts: str, chunks: range) -> None:
    """Remove the part files of `chunks`, whole or half-written. Other processes' chunks
    are left alone, and the folder too (another process may be about to write in it)."""
    if not os.path.isdir(parts):
        return
    for name in os.listdir(parts):
        match = re.fullmatch(r"part-(\d+)(\.partial)?\.npz", name)
        if match and int(match[1]) in chunks:
            os.remove(os.path.join(parts, name))
