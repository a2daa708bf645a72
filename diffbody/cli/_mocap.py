"""The `diffbody mocap` command: scale and register the body on a static marker trial, fit
every frame of a motion trial, write the fit (a pose file, .npz), the scaled body and a picture.

    diffbody mocap static.trc walk.trc --markerset opensim-gait --out fit.npz --png fit.png
    diffbody mocap static.trc walk.trc --markerset gait2354_Scale_MarkerSet.xml \
        --tasks subject01_Setup_IK.xml --mot angles.mot --trc model_markers.trc
"""

import dataclasses
import os
import time
import warnings
from pathlib import Path

import numpy as np

from ._args import add_body_args, body_from_args, check_output, finite_float

PICTURE_FRAMES = 4  # frames drawn in the PNG, evenly over the trial


def add_mocap_command(sub) -> None:
    """Add the `mocap` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser(
        "mocap",
        help="scale the body on a static marker trial and fit every frame of a motion (TRC/C3D)",
        description="Scales and registers the body (segment lengths, posture, marker offsets) "
        "on the static trial, then fits the posture of every frame of the motion trial to its "
        "markers. Marker files: .trc (units from the header) or .c3d (needs ezc3d).",
    )
    add_body_args(p)
    p.add_argument("static", help="static trial: the subject standing still (.trc or .c3d)")
    p.add_argument("motion", help="trial to fit, frame by frame (.trc or .c3d)")
    p.add_argument(
        "--markerset",
        default="opensim-gait",
        help="marker set: a shipped name (opensim-gait), a JSON file (data/markersets/), or "
        "an OpenSim marker set (.xml, or the <MarkerSet> of an .osim model)",
    )
    p.add_argument(
        "--tasks",
        default=None,
        help="OpenSim IK task set (a task-set file or an IK set-up file): which markers the "
        "motion fit uses (apply) and their weights; default: the marker set's weights",
    )
    p.add_argument(
        "--keep-zeros",
        action="store_true",
        help="read a marker at exactly (0, 0, 0) as a position, not as a gap (the default: "
        "many exporters write 'no data' so)",
    )
    p.add_argument(
        "--axes",
        default=None,
        help="the lab's axes in the files: opensim (Y up, X forward, Z right) or z-up "
        "(X forward, Y left, Z up); default: each file's own, opensim for .trc, and for "
        ".c3d its POINT:X_SCREEN/Y_SCREEN parameters, z-up where it has none",
    )
    p.add_argument(
        "--no-prior",
        action="store_true",
        help="scale on the markers alone, without the ANSUR II population prior on the "
        "body's proportions",
    )
    p.add_argument(
        "--time",
        nargs=2,
        type=finite_float,
        default=None,
        metavar=("T0", "T1"),
        help="fit only the frames with T0 <= time <= T1 (s)",
    )
    p.add_argument("--out", default="fit.npz", help="the fit's pose file (.npz, default fit.npz)")
    p.add_argument("--png", default=None, help="PNG of a few fitted frames with their markers")
    p.add_argument(
        "--curves",
        default=None,
        help="PNG of the fit over time: hip, knee, ankle angles and the marker error per frame",
    )
    p.add_argument(
        "--mot", default=None, help="ISB joint angles of every frame, degrees (OpenSim .mot)"
    )
    p.add_argument("--trc", default=None, help="the model's markers of every frame (.trc)")
    p.set_defaults(run=_mocap)


def _axes(text: str | None):
    """The lab axes named by --axes; None (not given) lets each file say its own."""
    from ..fitting._marker_trial import LAB_AXES

    if text is not None and text not in LAB_AXES:
        raise ValueError(f"--axes {text}: unknown lab axes; use one of {', '.join(LAB_AXES)}")
    return text


def _load_markerset(name_or_path: str, body):
    """A shipped or JSON marker set, or an OpenSim one (.xml, .osim)."""
    if name_or_path.lower().endswith((".xml", ".osim")):
        from ..fitting._opensim_files import load_opensim_markerset

        return load_opensim_markerset(name_or_path, body)
    from ..fitting._markerset import load_markerset

    return load_markerset(name_or_path, body)


def _noted(fn, *args, **kwargs):
    """fn's result; its warnings (markers one file has and the other lacks) printed as
    notes, one line each, instead of Python's warning format."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = fn(*args, **kwargs)
    for w in caught:
        print(f"note: {w.message}")
    return out


def _mocap(args) -> int:
    import jax

    from ..anthropometry._scaling import SCALE_GROUPS
    from ..files._pose_file import save_pose
    from ..files._saving import save_body
    from ..fitting._markers import read_markers
    from ..fitting._markerset import match_markers
    from ..fitting._motion_fit import fit_motion
    from ..fitting._opensim_files import read_ik_tasks
    from ..fitting._sphere_fit import FitStatus
    from ..fitting._static_fit import scale_and_register

    for flag, path, suffix in (
        ("--out", args.out, ".npz"),
        ("--png", args.png, ".png"),
        ("--curves", args.curves, ".png"),
        ("--mot", args.mot, ".mot"),
        ("--trc", args.trc, ".trc"),
    ):
        check_output(flag, path)
        if path is not None and not path.lower().endswith(suffix):
            raise ValueError(f"{flag} {path}: give a {suffix} file name")
    axes = _axes(args.axes)
    # The files before the body: a malformed marker file is told in milliseconds.
    zero_is_gap = not args.keep_zeros
    static = read_markers(args.static, axes=axes, zero_is_gap=zero_is_gap)
    motion = read_markers(args.motion, axes=axes, zero_is_gap=zero_is_gap)
    tasks = read_ik_tasks(args.tasks) if args.tasks else None
    if args.time is not None:
        whole, motion = motion, motion.between(*args.time)
        if len(motion.times) == 0:
            raise ValueError(
                f"--time {args.time[0]:g} {args.time[1]:g}: no frame of {args.motion} in that "
                f"range; its frames run {whole.times[0]:.3f}-{whole.times[-1]:.3f} s"
            )
    body = body_from_args(args)
    markerset = _noted(_load_markerset, args.markerset, body)

    t0 = time.perf_counter()
    static_fit = _noted(scale_and_register, body, static, markerset, prior=not args.no_prior)
    jax.block_until_ready(static_fit)
    scale_s = time.perf_counter() - t0
    registered, trial = _noted(match_markers, static_fit.markerset, motion)
    t0 = time.perf_counter()
    weights = None
    if tasks is not None:
        unused = [n for n in tasks if n not in registered.names]
        if unused:
            print(
                f"note: {args.tasks}: tasks for markers the fit lacks, ignored: {', '.join(unused)}"
            )
        weights = {n: w for n, w in tasks.items() if n in registered.names}
    out = _noted(
        fit_motion,
        static_fit.body,
        registered,
        trial,
        start=static_fit.pose,
        weights=weights,
        scale=static_fit.marker_scale,
        progress=True,
    )
    fit_s = time.perf_counter() - t0

    scaled = dataclasses.replace(static_fit.body, name=f"{body.name}-mocap")
    out_path = Path(args.out)
    body_path = save_body(scaled, out_path.with_name(f"{out_path.stem}.body.json"))
    per_marker = out.per_marker()
    save_pose(
        out_path,
        scaled,
        out.poses,
        times=out.times,
        status=[FitStatus(int(s)).name.lower() for s in np.asarray(out.status)],
        residuals={
            "rms": out.rms,  # (n_frames,) m over the markers
            "max": out.max,
            "errors": out.errors,  # (n_frames, n_markers) m, NaN where missing
            "outliers": out.outliers,  # (n_frames, n_markers) beyond the robust scale
        },
        scale={"groups": list(SCALE_GROUPS), "axial": static_fit.axial},
        overlays={"markers": {"names": list(out.names), "positions": trial.positions}},
        extra={
            "marker_kinds": list(out.kinds),
            "model_markers": out.markers,  # (n_frames, n_markers, 3) m, world
            "marker_rms": [per_marker[n][0] for n in out.names],
            "marker_max": [per_marker[n][1] for n in out.names],
            "static_marker_names": list(static_fit.markerset.names),
            "static_errors": static_fit.errors,
        },
    )

    rms = np.asarray(out.rms)
    status = np.asarray(out.status)
    converged = int(np.sum(status == FitStatus.CONVERGED))
    worst_frame = int(np.nanargmax(rms))
    static_rms = float(np.sqrt(np.mean(np.asarray(static_fit.errors) ** 2)))
    summary = out.summary()
    print(
        f"{args.static}: {len(static.names)} markers; scaled and registered in {scale_s:.1f} s, "
        f"marker RMS {100 * static_rms:.2f} cm"
    )
    print(
        f"{args.motion}: {len(out.times)} frames, {len(out.names)} markers fitted "
        f"in {fit_s:.1f} s ({len(out.times) / fit_s:.3g} frames/s), "
        f"{converged} of {len(out.times)} frames converged"
    )
    print(
        f"marker RMS: {100 * summary['inlier_rms']:.2f} cm over the inliers, "
        f"{100 * summary['rms']:.2f} cm over all markers (robust scale "
        f"{100 * out.scale:.1f} cm: an outlier is more than {100 * out.outlier_distance:.1f} "
        f"cm off); per frame mean {100 * np.nanmean(rms):.2f} cm, max "
        f"{100 * rms[worst_frame]:.2f} cm (t = {float(out.times[worst_frame]):.3f} s)"
    )
    flagged = out.flagged()
    if flagged:
        print(f"faulty markers ({len(flagged)}):")
        for name, why in flagged.items():
            print(f"  {name}: {why}")
    else:
        print("faulty markers: none")
    ranked = [n for n in per_marker if np.isfinite(per_marker[n][0]) and n not in flagged]
    if ranked:
        worst = max(ranked, key=lambda k: per_marker[k][0])
        print(
            f"worst other marker: {worst} (RMS {100 * per_marker[worst][0]:.2f} cm, "
            f"max {100 * per_marker[worst][1]:.2f} cm over the frames)"
        )
    spine_path = f" and {body_path.stem}.spine.json" if scaled.spine is not None else ""
    print(f"wrote {out_path} (the fit) and {body_path}{spine_path} (the scaled body)")
    if args.mot:
        from ..files._motion_files import write_mot

        write_mot(args.mot, out.times, out.angles(scaled), name=f"{out_path.stem} joint angles")
        print(f"wrote {args.mot} (ISB joint angles, degrees)")
    if args.trc:
        from ..fitting._marker_trial import MarkerTrial
        from ..fitting._trc import write_trc

        model = MarkerTrial(out.names, out.times, out.markers, trial.rate, args.trc)
        trc_axes = axes or "opensim"  # a TRC file is Y up unless --axes says otherwise
        write_trc(args.trc, model, axes=trc_axes)
        print(f"wrote {args.trc} (the model's markers, lab axes {trc_axes})")
    if args.png:
        picture(scaled, out, trial.positions, args.png, os.path.basename(args.motion))
        print(f"wrote {args.png}")
    if args.curves:
        from ..fitting._motion_plots import draw_motion

        draw_motion(out, scaled, title=os.path.basename(args.motion), path=args.curves)
        print(f"wrote {args.curves} (joint angles and marker error over time)")
    return 1 if np.any(status == FitStatus.FAILED) else 0


def draw_markers(ax, points, view="left", **style) -> None:
    """Scatter world points (n, 3) m over a `diffbody.draw`n body, in the same projection;
    NaN rows (missing markers) are skipped."""
    from .._render import camera

    points = np.asarray(points, float)
    points = points[np.all(np.isfinite(points), axis=1)]
    _, right, up, _ = camera(view)
    ax.scatter(points @ right, points @ up, zorder=5, **style)


def picture(body, fit, measured, path, title: str, view="left") -> Path:
    """A PNG of a few frames of a motion fit: the sphere body, the measured markers (blue
    rings) and the model's (red dots)."""
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
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
