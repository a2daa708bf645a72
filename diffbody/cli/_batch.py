"""The `diffbody batch` command: every row of a CSV of targets reached, one result row each in
a CSV written as the run goes.

A long run loses nothing (the machinery: diffbody/_streaming.py). The targets are read a
chunk of rows at a time (`--chunk-size`); each chunk is solved, its postures written as a
pose file `results.poses/part-00000.npz`, ..., then its rows appended to the results CSV in
one write, flushed and fsynced. A complete run merges the parts into `results.poses.npz`
and removes them. SIGINT or SIGTERM drops the chunk in flight, keeps every finished one and
exits 130 or 143; `--resume` checks the CSV's header against the run asked for (input file,
body, effectors, settings), cuts the file back to its last whole chunk and goes on from
there: the rows are those of an uninterrupted run.

The results CSV begins with `#` lines (``# key: value``, see `_header_fields`), then the
column names, then one row per target. Read it with
``csv.DictReader(line for line in f if not line.startswith("#"))`` or
``pandas.read_csv(path, comment="#")``.
"""

import os
import sys

from ._args import (
    add_body_args,
    add_solver_args,
    body_from_args,
    check_names,
    check_output,
    check_segments,
    positive_int,
)

FORMAT = "diffbody.batch/1"  # the results CSV's layout, its first header line


def add_batch_command(sub) -> None:
    """Add the `batch` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser("batch", help="reach every row of a CSV of targets (x,y,z per effector)")
    add_body_args(p)
    p.add_argument("targets", help="CSV: x,y,z per effector in order, header optional")
    p.add_argument("--effector", action="append", required=True, help="repeat for several")
    p.add_argument(
        "--out",
        default="results.csv",
        help="CSV to write (default results.csv); the postures go beside it (results.poses.npz)",
    )
    p.add_argument("--chunk-size", type=positive_int, default=4096, help="rows per compiled call")
    p.add_argument(
        "--resume",
        action="store_true",
        help="go on with an interrupted run's --out (same targets, body and settings) "
        "from its last finished chunk, instead of starting over",
    )
    add_solver_args(p)
    p.set_defaults(run=_batch)


# --- the targets, read a chunk at a time ----------------------------------------------------
def _target_lines(path: str, digest=None, block: int = 1 << 20):
    """The targets file's text lines, decoded a block of whole lines at a time (a UTF-8
    byte-order mark dropped); every byte read goes into `digest` (a hashlib object) when
    given."""
    import codecs
    import io
    from pathlib import Path

    if Path(path).is_dir():
        raise ValueError(f"{path}: is a directory; expected a CSV file of targets")
    lines_before, rest, first = 0, b"", True
    with open(path, "rb") as f:
        while True:
            read = f.read(block)
            if digest is not None:
                digest.update(read)
            if first and read.startswith(codecs.BOM_UTF8):
                read = read[len(codecs.BOM_UTF8) :]  # a spreadsheet's byte-order mark is no data
            first, data = False, rest + read
            if not data:
                return
            # Whole lines only (so no character is cut either), all that is left at the end.
            cut = data.rfind(b"\n") + 1 if read else len(data)
            chunk, rest = data[:cut], data[cut:]
            if not chunk:
                continue
            try:
                text = chunk.decode("utf-8")
            except UnicodeDecodeError as e:
                line = lines_before + chunk[: e.start].count(b"\n") + 1
                raise ValueError(
                    f"{path}: row {line}: not UTF-8 text (byte {chunk[e.start]:#04x}); "
                    "save the targets as a plain UTF-8 CSV"
                ) from None
            lines_before += chunk.count(b"\n")
            # A lone \r ends a line too (old spreadsheets), as when the file is read whole.
            yield from io.StringIO(text, newline="")


def _target_rows(path: str, k: int, digest=None):
    """The rows of x,y,z per effector (header optional), each a list of 3k floats, checked
    as they are read; errors name the file, and the row and column where there is one."""
    import csv

    example = ",".join(["0.35,0.30,1.10"] * k)
    shape = (
        f"each row is x,y,z in metres for each effector ({3 * k} columns), "
        f"comma-separated, e.g. {example}"
    )

    def number(cell):
        try:
            return float(cell)
        except ValueError:
            return None

    seen = {"bytes": False, "text": False}

    def lines():
        for line in _target_lines(path, digest):
            seen["bytes"] = True
            seen["text"] = seen["text"] or bool(line.strip())
            yield line

    n, header = 0, False
    reader = csv.reader(lines())
    for row in reader:
        line = reader.line_num
        row = [c.strip() for c in row]
        if len(row) == 3 * k:
            try:  # the common row, all numbers: none of the checks below can fail it
                values = [float(c) for c in row]
            except ValueError:
                pass
            else:
                n += 1
                yield values
                continue
        if not row or all(c == "" for c in row):
            continue
        for sep, name in ((";", "semicolons"), ("\t", "tabs")):
            if any(sep in c for c in row):
                raise ValueError(
                    f"{path}: row {line}: columns are separated by commas, not {name}; {shape}"
                )
        if any(len(c.split()) > 1 and all(number(x) is not None for x in c.split()) for c in row):
            raise ValueError(
                f"{path}: row {line}: columns are separated by commas, not spaces; {shape}"
            )
        values = [number(c) for c in row]
        if not n and not header and all(v is None for v in values):
            header = True  # the first row, all names
            continue
        if len(row) != 3 * k:
            col = min(len(row), 3 * k) + 1
            raise ValueError(
                f"{path}: row {line}, column {col}: expected {3 * k} columns "
                f"(x,y,z for each of {k} effector(s)), got {len(row)}"
            )
        for col, (cell, v) in enumerate(zip(row, values), start=1):
            if cell == "":
                raise ValueError(f"{path}: row {line}, column {col}: empty cell")
            if v is None:
                raise ValueError(f"{path}: row {line}, column {col}: not a number: {cell!r}")
        n += 1
        yield values
    if not seen["text"]:
        what = "the file is empty" if not seen["bytes"] else "only blank lines"
        raise ValueError(f"{path}: no target rows, {what}; {shape}")
    if not n:
        what = "a header but no target rows" if header else "no target rows"
        raise ValueError(f"{path}: {what}; {shape}")


def _scan_targets(path: str, k: int) -> tuple[str, int]:
    """One pass over the targets file before any solve: every row checked (a malformed row
    is told before hours of solving, not at its chunk), the rows counted and the bytes'
    SHA-256 (hex) taken."""
    import hashlib

    digest = hashlib.sha256()
    n = sum(1 for _ in _target_rows(path, k, digest))
    return digest.hexdigest(), n


def _target_chunks(path: str, k: int, chunk: int):
    """The targets as arrays (m, k, 3) of `chunk` rows (the last one fewer), read as they
    are needed: memory holds one chunk."""
    import numpy as np

    rows = []
    for values in _target_rows(path, k):
        rows.append(values)
        if len(rows) == chunk:
            yield np.asarray(rows, float).reshape(-1, k, 3)
            rows = []
    if rows:
        yield np.asarray(rows, float).reshape(-1, k, 3)


def _read_targets(path: str, k: int):
    """Rows of x,y,z per effector (header optional) -> (n, k, 3), read whole; errors as
    `_target_rows`."""
    import numpy as np

    return np.asarray(list(_target_rows(path, k)), float).reshape(-1, k, 3)


# --- what the results CSV records of its run ------------------------------------------------
def _poses_path(csv_path: str) -> str:
    """The postures file beside a results CSV: results.csv -> results.poses.npz."""
    root, _ = os.path.splitext(csv_path)
    return f"{root}.poses.npz"


def _parts_path(csv_path: str) -> str:
    """The folder of a run's postures, one pose file per finished chunk, until the run is
    complete: results.csv -> results.poses/."""
    root, _ = os.path.splitext(csv_path)
    return f"{root}.poses"


def _part_path(parts: str, index: int) -> str:
    """Chunk `index`'s pose file in the folder of parts."""
    return os.path.join(parts, f"part-{index:05d}.npz")


def dimensions_hash(body) -> str:
    """16 hex digits naming the body's dimensions (every numeric array of it, as float32 so
    that the name does not depend on JAX's precision setting)."""
    import hashlib

    import equinox as eqx
    import jax
    import numpy as np

    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(eqx.filter(body, eqx.is_array)):
        a = np.asarray(leaf)
        a = a.astype(np.float32) if np.issubdtype(a.dtype, np.floating) else a
        digest.update(f"{a.dtype}{a.shape}".encode())
        digest.update(np.ascontiguousarray(a).tobytes())
    return digest.hexdigest()[:16]


def _header_fields(args, body, sha256: str, total: int) -> list[tuple[str, str]]:
    """The results CSV's header: what produced it, in the order written. `--resume` checks
    all but `input` (the file may move; its hash is checked), `rows` (follows from the hash)
    and `begun` (the time the file was begun, UTC)."""
    from datetime import datetime, timezone

    import jax.numpy as jnp

    from ..files._pose_file import structure_hash

    return [
        ("format", FORMAT),
        ("input", args.targets),
        ("input-sha256", sha256),
        ("rows", str(total)),
        ("body", body.name),
        ("body-structure", structure_hash(body)),
        ("body-dimensions", dimensions_hash(body)),
        ("effectors", " ".join(args.effector)),
        ("segments", " ".join(args.segments) if args.segments else "(all)"),
        ("spine", "off" if args.no_spine else "on"),
        ("starts", str(args.starts)),
        ("chunk-size", str(args.chunk_size)),
        ("standing", "on"),  # solve_reach_batch's default; the command has no option for it
        ("float", jnp.dtype(jnp.result_type(float)).name),  # JAX_ENABLE_X64 changes the rows
        ("begun", datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")),
    ]


def _columns(effectors: list[str]) -> list[str]:
    """The results CSV's column names."""
    columns = ["row"]
    for e in effectors:
        columns += [f"{e}.residual", f"{e}.reached", f"{e}.valid"]
    return columns + ["status", "steps"]


# The settings a resumed run must share with the run that began the file, as a change of
# each is told.
_SETTINGS = {
    "effectors": "--effector",
    "segments": "--segments",
    "spine": "the spine (--no-spine)",
    "starts": "--starts",
    "chunk-size": "--chunk-size",
    "standing": "standing",
    "float": "the float precision (JAX_ENABLE_X64)",
}


def _changes(old: dict[str, str], new: dict[str, str]) -> list[str]:
    """What differs between a results file's header (`old`) and this run's (`new`), each
    told in words; empty when the run may go on with the file."""
    changes = []
    if old.get("input-sha256") != new["input-sha256"]:
        was = old.get("input-sha256", "(not recorded)")[:16]
        changes.append(f"the input file changed (sha256 {was}... vs {new['input-sha256'][:16]}...)")
    if any(old.get(key) != new[key] for key in ("body", "body-structure", "body-dimensions")):

        def said(h):
            return (
                f"{h.get('body')}: structure {h.get('body-structure')}, "
                f"dimensions {h.get('body-dimensions')}"
            )

        changes.append(f"the body changed ({said(old)} vs {said(new)})")
    for key, option in _SETTINGS.items():
        if old.get(key) != new[key]:
            changes.append(f"{option} changed from {old.get(key, '(not recorded)')} to {new[key]}")
    return changes


def _resume_point(out: str, fields, columns, chunk: int, total: int) -> int:
    """The rows of an interrupted run's `out` that this run keeps: its whole chunks whose
    postures are there too (or all, with `results.poses.npz`, of a complete run). Cuts the
    file back to them and removes the parts of later chunks. A header that differs from
    this run's is refused, naming what changed."""
    from .._streaming import read_results, truncate

    have = read_results(out)
    if have.fields.get("format") != FORMAT:
        found = have.fields.get("format")
        raise ValueError(
            f"--resume {out}: not a `diffbody batch` file of format {FORMAT} (its header "
            f"{'says ' + repr(found) if found else 'is missing'}); rerun without --resume "
            "to start over"
        )
    changes = _changes(have.fields, dict(fields))
    if changes:
        raise ValueError(
            f"--resume {out}: {'; '.join(changes)}; rerun as it was begun, or without "
            "--resume to start over"
        )
    if have.columns != columns:
        raise ValueError(
            f"--resume {out}: its columns are {','.join(have.columns)}, not "
            f"{','.join(columns)}; rerun without --resume to start over"
        )
    for i, cell in enumerate(have.first_cells):
        if cell != str(i):
            raise ValueError(
                f"--resume {out}: result row {i + 1} is numbered {cell!r}, not {i} (the file "
                "was edited); rerun without --resume to start over"
            )
    rows = min(len(have.ends), total)
    chunks = -(-total // chunk) if rows == total else rows // chunk
    parts, poses = _parts_path(out), _poses_path(out)
    complete = rows == total and os.path.exists(poses) and not os.path.exists(parts)
    if not complete:
        present = 0
        while present < chunks and os.path.exists(_part_path(parts, present)):
            present += 1
        chunks = present
        _remove_file(poses)  # an earlier run's
    keep = min(chunks * chunk, total)
    truncate(out, have.ends[keep - 1] if keep else have.start)
    _remove_parts(parts, chunks)
    return keep


def _remove_file(path: str) -> None:
    if os.path.exists(path):
        os.remove(path)


def _remove_parts(parts: str, first: int) -> None:
    """Remove the part files of chunks `first`.. and any half-written one (the folder too,
    when that leaves it empty)."""
    import re

    if not os.path.isdir(parts):
        return
    for name in os.listdir(parts):
        match = re.fullmatch(r"part-(\d+)(\.partial)?\.npz", name)
        if match and (match[2] or int(match[1]) >= first):
            os.remove(os.path.join(parts, name))
    if not os.listdir(parts):
        os.rmdir(parts)


# --- the run ---------------------------------------------------------------------------------
class _Run:
    """How far the run got: what the interrupt message tells."""

    def __init__(self, out: str, total: int):
        self.out, self.total = out, total
        self.begun = False  # whether `out` holds this run's header
        self.done = 0  # rows written whole, with their postures
        self.bar = None


def _batch(args) -> int:
    from .._streaming import Interrupted, Interrupts

    check_output("--out", args.out)
    k = len(args.effector)
    # The file before the body: a malformed CSV is told before any loading or solving.
    sha256, total = _scan_targets(args.targets, k)
    if os.path.exists(args.out) and os.path.samefile(args.out, args.targets):
        raise ValueError(f"--out {args.out}: is the targets file; give another file name")
    body = body_from_args(args)
    check_names(body, args.effector, args.segments)
    note = check_segments(body, args.effector, args.segments)
    if note:
        print(note)
    run = _Run(args.out, total)
    with Interrupts() as signals:
        try:
            return _stream(args, body, _header_fields(args, body, sha256, total), run, signals)
        except (Interrupted, KeyboardInterrupt) as e:
            # KeyboardInterrupt: a SIGINT the handler did not see (raised inside a JAX call).
            code = e.code if isinstance(e, Interrupted) else 130
            if run.bar is not None and run.bar.bar is not None:
                run.bar.bar.close()
            if run.begun:
                message = (
                    f"interrupted after {run.done} of {total} rows; {args.out} holds them; "
                    "rerun with --resume"
                )
            else:
                message = f"interrupted before {args.out} was begun; nothing written"
            print(message, file=sys.stderr)
            return code


def _stream(args, body, fields, run: _Run, signals) -> int:
    """Solve the chunks not yet in `args.out` and append them; merge the postures at the
    end. Returns the exit status."""
    from .._progress import Progress
    from .._streaming import append_lines, header_text, replace_atomically

    out, total, k = args.out, run.total, len(args.effector)
    chunk = min(args.chunk_size, total)
    columns = _columns(args.effector)
    parts, poses = _parts_path(out), _poses_path(out)
    with signals.held():
        if args.resume and os.path.exists(out):
            run.done = _resume_point(out, fields, columns, chunk, total)
            print(f"resuming {out} after {run.done} of {total} rows")
        else:
            if args.resume:
                print(f"--resume: no {out} yet; starting from the first row")
            _remove_parts(parts, 0)
            _remove_file(poses)
            replace_atomically(out, header_text(fields, columns))
        run.begun = True
    run.bar = Progress(total, True, "reach", "solve")
    run.bar.update(run.done)
    for index, xyz in enumerate(_target_chunks(args.targets, k, chunk)):
        at = index * chunk
        if at < run.done:
            continue
        result = _solve_chunk(body, args, xyz, chunk)
        text = _rows_text(result, at)
        with signals.held():  # the chunk's postures, then its rows: a row has its posture
            _write_part(parts, index, body, result, xyz, args.effector)
            append_lines(out, text)
            run.done = at + len(xyz)
        run.bar.update(run.done)
    if not (os.path.exists(poses) and not os.path.exists(parts)):
        _merge_parts(parts, -(-total // chunk), poses, body, args.effector)
        _remove_parts(parts, 0)
    reached = _rows_reached(out, args.effector)
    print(f"{reached} of {total} rows reached; wrote {out} and {poses} (the postures)")
    return 0


def _solve_chunk(body, args, xyz, chunk: int):
    """One chunk's `ReachResult` (host arrays, one row per target row)."""
    import jax
    import numpy as np

    from ..ik._reach_batch import solve_reach_batch

    m, k = xyz.shape[:2]
    # The last chunk is padded to the others' size with NaN rows, so that every chunk runs
    # the same compiled solves; a NaN row is flagged invalid at once and costs no further
    # starts. The padding is dropped.
    padded = np.concatenate([xyz, np.full((chunk - m, k, 3), np.nan)]) if m < chunk else xyz
    out = solve_reach_batch(
        body,
        args.effector,
        padded,
        chunk_size=chunk,
        progress=False,
        spine=not args.no_spine,
        segments=args.segments,
        starts=args.starts,
    )
    return jax.tree.map(lambda a: np.asarray(a)[:m], out)


def _status_names(status) -> list[str]:
    from ..ik._reach import ReachStatus

    return [ReachStatus(int(s)).name.lower() for s in status]


def _rows_text(result, at: int) -> str:
    """A chunk's result rows as CSV lines, numbered from `at`."""
    import csv
    import io

    text = io.StringIO()
    w = csv.writer(text, lineterminator="\n")
    k = result.residuals.shape[1]
    for i, status in enumerate(_status_names(result.status)):
        cells = [at + i]
        for j in range(k):
            cells += [
                f"{float(result.residuals[i, j]):.9g}",
                int(result.reached[i, j]),
                int(result.valid[i, j]),
            ]
        w.writerow(cells + [status, int(result.steps[i])])
    return text.getvalue()


def _write_part(parts: str, index: int, body, result, xyz, effectors) -> None:
    """A chunk's postures as a pose file in the folder of parts, whole or not at all."""
    from .._streaming import fsync_file
    from ..files._pose_file import save_pose

    os.makedirs(parts, exist_ok=True)
    path = _part_path(parts, index)
    tmp = path[: -len(".npz")] + ".partial.npz"
    save_pose(tmp, body, result.pose, **_pose_fields(result, xyz, effectors))
    fsync_file(tmp)
    os.replace(tmp, path)


def _pose_fields(result, xyz, effectors) -> dict:
    """What a batch's pose file holds beside the postures (`save_pose`'s keywords)."""
    return dict(
        kind="batch",
        status=_status_names(result.status),
        residuals={"targets": result.residuals},
        overlays={"targets": {"names": list(effectors), "points": xyz}},
        extra={"reached": result.reached, "valid": result.valid, "steps": result.steps},
    )


def _merge_parts(parts: str, n: int, poses: str, body, effectors) -> None:
    """The `n` parts' postures as one pose file, `poses`, written whole or not at all."""
    import equinox as eqx
    import jax
    import numpy as np

    from .._spine import spine_angles
    from .._streaming import fsync_file
    from ..files._pose_file import load_pose, save_pose

    # float64 while reading: the angles go back as they were written, not via float32.
    with jax.enable_x64(True):
        records = [load_pose(_part_path(parts, i), body) for i in range(n)]
        poses_read = [r.pose for r in records]
        if any(p.spine_target is not None for p in poses_read):
            # A chunk whose rows the limbs alone reached names no spine target; where the
            # trunk moved in another chunk, it is the start's spine, as one solve names it.
            rest = np.asarray(spine_angles(body, body.spine, body.rest_pose()).sum(0))
            poses_read = [
                p
                if p.spine_target is not None
                else eqx.tree_at(
                    lambda q: q.spine_target,
                    p,
                    np.repeat(rest[None], r.n_frames, 0),
                    is_leaf=lambda x: x is None,
                )
                for p, r in zip(poses_read, records)
            ]
        pose = jax.tree.map(lambda *a: np.concatenate([np.asarray(x) for x in a]), *poses_read)

        def joined(get, dtype):
            return np.concatenate([np.asarray(get(r), dtype) for r in records])

        tmp = poses[: -len(".npz")] + ".partial.npz"
        save_pose(
            tmp,
            body,
            pose,
            kind="batch",
            status=[s for r in records for s in r.status],
            residuals={"targets": joined(lambda r: r.residuals["targets"], float)},
            overlays={
                "targets": {
                    "names": list(effectors),
                    "points": joined(lambda r: r.overlays["targets"]["points"], float),
                }
            },
            extra={
                "reached": joined(lambda r: r.extra["reached"], bool),
                "valid": joined(lambda r: r.extra["valid"], bool),
                "steps": joined(lambda r: r.extra["steps"], int),
            },
        )
    fsync_file(tmp)
    os.replace(tmp, poses)


def _rows_reached(out: str, effectors: list[str]) -> int:
    """The rows of a results CSV whose every effector reached its target."""
    import csv

    with open(out, newline="", encoding="utf-8") as f:
        rows = csv.DictReader(line for line in f if not line.startswith("#"))
        return sum(all(row[f"{e}.reached"] == "1" for e in effectors) for row in rows)
