"""The `diffbody` command line."""

import argparse
import dataclasses
import math
import os
import sys


def keep_compiled() -> None:
    """Turn on JAX's persistent compilation cache for the command line, so that a repeated
    `reach` or `batch` reuses what an earlier run compiled (README, "Benchmarks"). The
    folder is $JAX_COMPILATION_CACHE_DIR when set, else $XDG_CACHE_HOME/diffbody/jax
    (~/.cache/diffbody/jax); DIFFBODY_NO_CACHE=1 leaves the cache off. Every compiled
    function is kept, however quick to compile (JAX keeps only those over 1 s by default):
    reading one back costs a few milliseconds, compiling it tens."""
    from pathlib import Path

    import jax

    if os.environ.get("DIFFBODY_NO_CACHE") == "1":
        return
    if not jax.config.jax_compilation_cache_dir:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
        jax.config.update("jax_compilation_cache_dir", str(base / "diffbody" / "jax"))
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def _positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer (1, 2, ...), got {text!r}")
    return value


def finite_float(text: str) -> float:
    """argparse type: a finite number (nan and inf parse as floats but are no position)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number in metres, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def _view(text: str):
    """argparse type: a named view or "AZ,EL" (camera azimuth and elevation, degrees)."""
    from .._render import VIEWS

    if text in VIEWS:
        return text
    parts = text.split(",")
    try:
        az, el = (float(x) for x in parts)
    except ValueError:
        az = el = math.nan
    if not (math.isfinite(az) and math.isfinite(el)):
        raise argparse.ArgumentTypeError(
            f"unknown view {text!r}; use one of {', '.join(VIEWS)} "
            "or AZ,EL (camera azimuth and elevation in degrees, e.g. 30,15)"
        )
    return (az, el)


def check_output(option: str, path: str | None) -> None:
    """Refuse an output file that cannot be written, before any loading or solving, so a
    typo in a folder name does not cost a whole solve."""
    if path is None:
        return
    if not path:
        raise ValueError(f"{option}: empty file name")
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise ValueError(f"{option} {path}: is a folder; give a file name")
    if not os.path.exists(folder):
        raise ValueError(f"{option} {path}: folder {folder} does not exist")
    if not os.path.isdir(folder):
        raise ValueError(f"{option} {path}: {folder} is not a folder")
    if not os.access(folder, os.W_OK):
        raise ValueError(f"{option} {path}: cannot write in folder {folder}")


def body_from_args(args):
    from ..files._body_file import load_body

    return load_body(args.body, variant=args.variant)


def _check_names(body, effectors: list[str], segments: list[str] | None) -> None:
    """Unknown effector or segment names, reported with the option before any solve."""
    from ..ik._targets import Target, resolve_targets

    hint = " (diffbody info --names lists them)"
    try:
        resolve_targets(body, [Target.position(e, [0.0, 0.0, 0.0]) for e in effectors])
    except KeyError as e:
        raise KeyError(f"--effector: {e.args[0]}{hint}") from None
    for name in segments or []:
        try:
            body.segment_index(name)
        except KeyError as e:
            raise KeyError(f"--segments: {e.args[0]}{hint}") from None


def _summary(body) -> str:
    import jax.numpy as jnp

    from .._kinematics import forward

    fk = forward(body, body.rest_pose())
    top = float(jnp.max(fk.sphere_centers[:, 2] + fk.sphere_radii))
    cog = [round(float(c), 4) for c in fk.center_of_gravity]
    return (
        f"body {body.name!r} ({body.source}): {body.n_segments} segments, {body.n_joints} joints, "
        f"{body.n_spheres} spheres, {len(body.feature_names)} features\n"
        f"standard position: stature {top:.4f} m, mass {float(jnp.sum(body.masses)):.2f} kg, "
        f"center of gravity {cog} m"
    )


def _render(args) -> int:
    from .._render import render

    check_output("--out", args.out)
    body = body_from_args(args)
    print(_summary(body))
    path = render(
        body,
        body.rest_pose(),
        args.out,
        args.view,
        features=args.features,
        skeleton=args.skeleton,
        title=f"diffbody {body.name}: standard position",
    )
    print(f"wrote {path}")
    return 0


def _info(args) -> int:
    body = body_from_args(args)
    print(_summary(body))
    if args.names:
        print("segments:", ", ".join(body.segment_names))
        print("joints:", ", ".join(body.joint_names))
        print("features:", ", ".join(body.feature_names))
    return 0


def _verdict(out, k: int) -> str:
    """One target's outcome in words: "reached, residual 0.07 mm" or "not reached: closest
    12.3 mm, target outside the reach envelope"."""
    from ..ik._reach import ReachStatus

    mm = 1000.0 * float(out.residuals[k])
    if not bool(out.valid[k]):
        return ReachStatus.INVALID_TARGET.describe()
    if bool(out.reached[k]):
        return f"reached, residual {mm:.2g} mm"
    why = (
        "target outside the reach envelope"
        if bool(out.beyond[k])
        else "no posture found within 1 mm"
    )
    return f"not reached: closest {mm:.1f} mm, {why}"


def _reach(args) -> int:
    import json

    import numpy as np

    from ..ik._reach import ReachStatus, solve_reach
    from ..ik._targets import Target

    check_output("--out", args.out)
    check_output("--png", args.png)
    body = body_from_args(args)
    _check_names(body, [args.effector], args.segments)
    target = np.asarray(args.target, float)
    out = solve_reach(
        body,
        [Target.position(args.effector, target)],
        spine=not args.no_spine,
        segments=args.segments,
        starts=args.starts,
    )
    rest = np.asarray(body.rest_pose().angles)
    angles = np.degrees(np.asarray(out.pose.angles))
    verdict = _verdict(out, 0)
    print(f"{args.effector} -> {target.tolist()} m: {verdict} ({int(out.steps)} solver steps)")
    # Angle changes wrapped into (-180, 180]: theta 179 -> -179 moved 2 degrees, not 358.
    change = (angles - np.degrees(rest) + 180.0) % 360.0 - 180.0
    moved = np.max(np.abs(change), axis=1)
    main = [i for i in np.argsort(-moved)[:8] if moved[i] > 0.1]
    print("main joint angles (theta, phi, tau) in degrees:")
    for i in sorted(main):
        th, ph, ta = angles[i]
        print(f"  {body.segment_names[i]:<16} {th:8.2f} {ph:8.2f} {ta:8.2f}")
    spine_target = out.pose.spine_target
    if spine_target is not None:
        spine_target = np.degrees(np.asarray(spine_target)).tolist()
        print("  spine target (flexion, axial, lateral) deg:", [round(a, 2) for a in spine_target])
    if args.out:
        data = {
            "effector": args.effector,
            "target": target.tolist(),
            "angles_deg": {n: angles[i].tolist() for i, n in enumerate(body.segment_names)},
            "position": np.asarray(out.pose.position).tolist(),
            "spine_target_deg": spine_target,
            "residuals": np.asarray(out.residuals).tolist(),
            "reached": np.asarray(out.reached).tolist(),
            "status": ReachStatus(int(out.status)).name.lower(),
            "steps": int(out.steps),
        }
        with open(args.out, "w") as f:
            json.dump(data, f, indent=1)
        print(f"wrote {args.out}")
    if args.png:
        from .._render import render

        path = render(
            body,
            out.pose,
            args.png,
            ["front", "left", "perspective"],
            title=f"diffbody {body.name}: reach {args.effector}",
        )
        print(f"wrote {path}")
    return 0


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


def _batch(args) -> int:
    import csv

    from ..ik._reach import ReachStatus
    from ..ik._reach_batch import solve_reach_batch

    check_output("--out", args.out)
    # The file before the body: a malformed CSV is told in milliseconds.
    xyz = _read_targets(args.targets, len(args.effector))
    if os.path.exists(args.out) and os.path.samefile(args.out, args.targets):
        raise ValueError(f"--out {args.out}: is the targets file; give another file name")
    body = body_from_args(args)
    _check_names(body, args.effector, args.segments)
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
    n_reached = int(out.reached.all(axis=1).sum())
    print(f"{n_reached} of {xyz.shape[0]} rows reached; wrote {args.out}")
    return 0


def _scale(args) -> int:
    from ..anthropometry._measurements import MEASUREMENT_NAMES, measurements
    from ..anthropometry._scale_to import scale_to
    from ..files._saving import save_body

    check_output("--out", args.out)
    check_output("--png", args.png)
    given = {n: getattr(args, n) for n in MEASUREMENT_NAMES if getattr(args, n) is not None}
    body = scale_to(None, given, sex=args.sex)
    body = dataclasses.replace(body, name=args.name or f"{args.sex}-scaled")
    path = save_body(body, args.out)
    print(f"wrote {path}" + (f" and {path.stem}.spine.json" if body.spine else ""))
    print("measurement                      value  (given *)")
    for name, value in measurements(body).items():
        unit = "kg" if name == "weightkg" else "m"
        print(f"  {name:<30} {value:8.4f} {unit}{' *' if name in given else ''}")
    if args.png:
        from .._render import render

        render(body, body.rest_pose(), args.png, ["front", "left"], title=f"diffbody {body.name}")
        print(f"wrote {args.png}")
    return 0


def _read_cloud(path: str):
    """centers (m, 3), radii (m,) and correspondences (m,) or None from an .npz file."""
    import numpy as np

    try:
        data = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as e:
        if isinstance(e, (FileNotFoundError, IsADirectoryError, PermissionError)):
            raise
        raise ValueError(
            f"{path}: not a NumPy .npz file ({e}); write one with "
            "numpy.savez(path, centers=(m, 3) array in m, radii=(m,) array in m)"
        ) from None
    if not hasattr(data, "files"):
        raise ValueError(f"{path}: a single array, not an .npz archive of named arrays")
    for key in ("centers", "radii"):
        if key not in data.files:
            raise ValueError(
                f"{path}: no array {key!r} (found {sorted(data.files)}); give centers=(m, 3) "
                "and radii=(m,) in m, and optionally correspondences=(m,) model sphere indices"
            )
    match = data["correspondences"] if "correspondences" in data.files else None
    return data["centers"], data["radii"], match


def _fit(args) -> int:
    import json

    import numpy as np

    from ..files._saving import save_body
    from ..fitting._sphere_fit import INLIER_DISTANCE, FitStatus, fit_spheres

    check_output("--out", args.out)
    check_output("--png", args.png)
    body = body_from_args(args)
    centers, radii, match = _read_cloud(args.cloud)
    try:
        out = fit_spheres(body, centers, radii, correspondences=match, fit=tuple(args.fit))
    except ValueError as e:
        raise ValueError(f"{args.cloud}: {e}") from None
    fitted = dataclasses.replace(out.body, name=args.name or f"{body.name}-fitted")
    status = FitStatus(int(out.status)).name.lower()
    inliers = np.asarray(out.inliers)
    residual = np.asarray(out.residuals)[inliers]
    print(
        f"{args.cloud}: {len(inliers)} spheres, {int(inliers.sum())} inliers (within "
        f"{1000 * INLIER_DISTANCE:.0f} mm); fit {status} in {int(out.steps)} solver steps"
    )
    if residual.size:
        print(f"inlier residual: median {1000 * np.median(residual):.1f} mm")
    from ..anthropometry._scaling import SCALE_GROUPS

    print("scale group        axial  radial")
    for name, a, r in zip(SCALE_GROUPS, np.asarray(out.axial), np.asarray(out.radial)):
        print(f"  {name:<15} {a:7.4f} {r:7.4f}")
    path = save_body(fitted, args.out)
    pose_path = path.with_name(f"{path.stem}.pose.json")
    angles = np.degrees(np.asarray(out.pose.angles))
    spine = out.pose.spine_target
    data = {
        "cloud": args.cloud,
        "status": status,
        "steps": int(out.steps),
        "position": np.asarray(out.pose.position).tolist(),
        "angles_deg": {n: angles[i].tolist() for i, n in enumerate(body.segment_names)},
        "spine_target_deg": None if spine is None else np.degrees(np.asarray(spine)).tolist(),
        "axial": dict(zip(SCALE_GROUPS, np.asarray(out.axial).tolist())),
        "radial": dict(zip(SCALE_GROUPS, np.asarray(out.radial).tolist())),
        "residuals": np.asarray(out.residuals).tolist(),
        "inliers": inliers.tolist(),
    }
    with open(pose_path, "w") as f:
        json.dump(data, f, indent=1)
    print(f"wrote {path} (the fitted body) and {pose_path} (its pose and the fit)")
    if args.png:
        from .._render import render

        render(
            fitted,
            out.pose,
            args.png,
            ["front", "left"],
            title=f"diffbody fit: {os.path.basename(args.cloud)} (outliers in red)",
            cloud=(centers, radii, inliers),
        )
        print(f"wrote {args.png}")
    return 0 if out.status != FitStatus.FAILED else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="diffbody", description="Differentiable kinematics of sphere-skinned bodies."
    )
    sub = parser.add_subparsers(dest="command", required=True)

    def body_args(p):
        p.add_argument("--variant", default="male50", help="embedded body: male50 or female50")
        p.add_argument("--body", default=None, help="a body JSON file instead (data/SCHEMA.md)")

    p = sub.add_parser("render", help="draw the body in its standard position to a PNG")
    body_args(p)
    p.add_argument("--out", default="body.png", help="PNG to write (default body.png)")
    p.add_argument(
        "--view",
        nargs="+",
        type=_view,
        default=["front", "left", "perspective"],
        help="views: front, back, left, right, top, perspective, or AZ,EL degrees",
    )
    p.add_argument("--features", action="store_true", help="mark the named features")
    p.add_argument("--skeleton", action="store_true", help="draw the segment axes")
    p.set_defaults(run=_render)

    p = sub.add_parser("info", help="summarise a body")
    body_args(p)
    p.add_argument("--names", action="store_true", help="list segments, joints and features")
    p.set_defaults(run=_info)

    def solver_args(p):
        p.add_argument("--no-spine", action="store_true", help="keep the spine at rest")
        p.add_argument(
            "--segments", nargs="+", default=None, help="only these segments move (names)"
        )
        p.add_argument(
            "--starts", type=_positive_int, default=8, help="most solver starts (default 8)"
        )

    p = sub.add_parser("reach", help="reach one target with an effector (inverse kinematics)")
    body_args(p)
    p.add_argument("--effector", required=True, help="joint, feature or center_of_gravity")
    p.add_argument("--target", nargs=3, type=finite_float, required=True, metavar=("X", "Y", "Z"))
    p.add_argument("--out", default=None, help="JSON to write (angles in degrees)")
    p.add_argument("--png", default=None, help="PNG of the pose to write")
    solver_args(p)
    p.set_defaults(run=_reach)

    p = sub.add_parser("batch", help="reach every row of a CSV of targets (x,y,z per effector)")
    body_args(p)
    p.add_argument("targets", help="CSV: x,y,z per effector in order, header optional")
    p.add_argument("--effector", action="append", required=True, help="repeat for several")
    p.add_argument("--out", default="results.csv", help="CSV to write (default results.csv)")
    p.add_argument("--chunk-size", type=_positive_int, default=4096, help="rows per compiled call")
    solver_args(p)
    p.set_defaults(run=_batch)

    p = sub.add_parser(
        "scale",
        help="scale the default body to measurements (metres, weight in kg)",
        description="Measurements not given follow the ANSUR II population given those that are.",
    )
    p.add_argument("--sex", required=True, choices=["male", "female"])
    p.add_argument("--out", required=True, help="body JSON to write (data/SCHEMA.md)")
    p.add_argument("--png", default=None, help="PNG of the scaled body to write")
    p.add_argument("--name", default=None, help="the body's name in the file")
    p.add_argument("--weight", dest="weightkg", type=positive_float, help="kg")
    from ..anthropometry._measurements import MEASUREMENTS

    for name, m in MEASUREMENTS.items():
        if name != "weightkg":
            p.add_argument(f"--{name}", type=positive_float, metavar="M", help=m.definition)
    p.set_defaults(run=_scale)

    p = sub.add_parser(
        "fit",
        help="fit the body's dimensions and pose to a measured sphere cloud (.npz)",
        description="The cloud: numpy.savez(path, centers=(m, 3), radii=(m,)) in metres, "
        "optionally correspondences=(m,) model sphere indices (-1 for none).",
    )
    body_args(p)
    p.add_argument("cloud", help=".npz with centers, radii (m) [, correspondences]")
    p.add_argument("--out", required=True, help="fitted body JSON to write (data/SCHEMA.md)")
    p.add_argument("--png", default=None, help="PNG of the fitted body over the cloud")
    p.add_argument("--name", default=None, help="the fitted body's name in the file")
    p.add_argument(
        "--fit",
        nargs="+",
        choices=["pose", "lengths", "radii"],
        default=["pose", "lengths", "radii"],
        help="what moves (default all three)",
    )
    p.set_defaults(run=_fit)

    # Their modules import this one's helpers: imported here, not at the top.
    from ._mocap import add_mocap_command
    from ._webb import add_webb_command

    add_mocap_command(sub)
    add_webb_command(sub)

    args = parser.parse_args(argv)
    if argv is None and args.command in ("reach", "batch", "scale", "fit", "mocap", "webb"):
        keep_compiled()
    try:
        return args.run(args)
    except KeyError as e:  # its str() would quote the message
        message = e.args[0] if e.args else repr(e)
    except OSError as e:  # FileNotFoundError, IsADirectoryError, PermissionError, ...
        message = f"{e.filename}: {e.strerror}" if e.filename and e.strerror else str(e)
    except ValueError as e:  # BodyFileError, a malformed CSV, UnicodeDecodeError, ...
        message = str(e)
    print(f"diffbody: error: {message}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
