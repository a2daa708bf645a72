"""The `diffbody batch` command: every row of a CSV of targets reached, one result row each in
a CSV written."""

import os

from ._args import (
    add_body_args,
    add_solver_args,
    body_from_args,
    check_names,
    check_output,
    check_segments,
    positive_int,
)


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
    add_solver_args(p)
    p.set_defaults(run=_batch)


def _read_targets(path: str, k: int):
    """Rows of x,y,z per effector (header optional) -> (n, k, 3); errors name the file, and
    the row and column where there is one."""
    import csv
    import io
    from pathlib import Path

    import numpy as np

    example = ",".join(["0.35,0.30,1.10"] * k)
    shape = (
        f"each row is x,y,z in metres for each effector ({3 * k} columns), "
        f"comma-separated, e.g. {example}"
    )
    if Path(path).is_dir():
        raise ValueError(f"{path}: is a directory; expected a CSV file of targets")
    data = Path(path).read_bytes()
    try:
        text = data.decode("utf-8-sig")  # a spreadsheet's byte-order mark is no data
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        raise ValueError(
            f"{path}: row {line}: not UTF-8 text (byte {data[e.start]:#04x}); "
            "save the targets as a plain UTF-8 CSV"
        ) from None
    if not text.strip():
        what = "the file is empty" if not data else "only blank lines"
        raise ValueError(f"{path}: no target rows, {what}; {shape}")

    def number(cell):
        try:
            return float(cell)
        except ValueError:
            return None

    rows, header = [], False
    reader = csv.reader(io.StringIO(text, newline=""))
    for row in reader:
        line = reader.line_num
        row = [c.strip() for c in row]
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
        if not rows and not header and all(v is None for v in values):
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
        rows.append(values)
    if not rows:
        what = "a header but no target rows" if header else "no target rows"
        raise ValueError(f"{path}: {what}; {shape}")
    return np.asarray(rows, float).reshape(-1, k, 3)


def _poses_path(csv_path: str) -> str:
    """The postures file beside a results CSV: results.csv -> results.poses.npz."""
    root, _ = os.path.splitext(csv_path)
    return f"{root}.poses.npz"


def _batch(args) -> int:
    import csv

    import numpy as np

    from ..files._pose_file import save_pose
    from ..ik._reach import ReachStatus
    from ..ik._reach_batch import solve_reach_batch

    check_output("--out", args.out)
    # The file before the body: a malformed CSV is told in milliseconds.
    xyz = _read_targets(args.targets, len(args.effector))
    if os.path.exists(args.out) and os.path.samefile(args.out, args.targets):
        raise ValueError(f"--out {args.out}: is the targets file; give another file name")
    body = body_from_args(args)
    check_names(body, args.effector, args.segments)
    note = check_segments(body, args.effector, args.segments)
    if note:
        print(note)
    out = solve_reach_batch(
        body,
        args.effector,
        xyz,
        chunk_size=args.chunk_size,
        spine=not args.no_spine,
        segments=args.segments,
        starts=args.starts,
    )
    header = ["row"]
    for e in args.effector:
        header += [f"{e}.residual", f"{e}.reached", f"{e}.valid"]
    header += ["status", "steps"]
    with open(args.out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for i in range(xyz.shape[0]):
            cells = [i]
            for j in range(len(args.effector)):
                cells += [
                    f"{float(out.residuals[i, j]):.9g}",
                    int(out.reached[i, j]),
                    int(out.valid[i, j]),
                ]
            w.writerow(cells + [ReachStatus(int(out.status[i])).name.lower(), int(out.steps[i])])
    poses = _poses_path(args.out)
    save_pose(
        poses,
        body,
        out.pose,
        kind="batch",
        status=[ReachStatus(int(s)).name.lower() for s in np.asarray(out.status)],
        residuals={"targets": out.residuals},
        overlays={"targets": {"names": list(args.effector), "points": xyz}},
        extra={"reached": out.reached, "valid": out.valid, "steps": out.steps},
    )
    n_reached = int(out.reached.all(axis=1).sum())
    rows = xyz.shape[0]
    print(f"{n_reached} of {rows} rows reached; wrote {args.out} and {poses} (the postures)")
    return 0
