"""The `diffbody mocap` command: scale and register the body on a static marker trial, fit
every frame of a motion trial, write the fit (a pose file, .npz), the scaled body and a picture.

    diffbody mocap static.trc walk.trc --markerset opensim-gait --out fit.npz --png fit.png
    diffbody mocap static.trc walk.trc --markerset gait2354_Scale_MarkerSet.xml \
        --tasks subject01_Setup_IK.xml --mot angles.mot --trc model_markers.trc

With a folder of trials, or a quoted glob pattern, the static registration is done once and
every trial fitted against it, each trial's files written into the --out folder as it
finishes, with a summary CSV that `--resume` goes on from (`diffbody.fitting.fit_trials`):

    diffbody mocap static.trc trials/ --out fits/ --mot --png
    diffbody mocap static.trc 'trials/*.trc' --out fits/ --resume
"""

import glob
import os
import sys
import time
from pathlib import Path

import numpy as np

from ._args import add_body_args, body_from_args, check_output, finite_float, non_negative_int

FLAG = True  # an output option given alone: with several trials, each trial's file


def add_mocap_command(sub) -> None:
    """Add the `mocap` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser(
        "mocap",
        help="scale the body on a static marker trial and fit every frame of a motion (TRC/C3D), "
        "or of every trial of a folder",
        description="Scales and registers the body (segment lengths, posture, marker offsets) "
        "on the static trial, then fits the posture of every frame of the motion trial to its "
        "markers. Marker files: .trc (units from the header) or .c3d (needs ezc3d). Given a "
        "folder of trials (its .trc and .c3d files, by name) or a quoted glob pattern "
        "('trials/*.trc'), the registration is done once and every trial fitted against it; "
        "--out is then a folder (default fits/) that gets, as each trial finishes, NAME.npz "
        "(its fit) and the outputs asked for (--mot, --angles, --trc, --png, --curves given alone: "
        "NAME.mot, NAME.angles.mot, NAME.model.trc, NAME.png, NAME.curves.png), the scaled "
        "body once "
        "(body.json) and a row in trials.csv (frames, status, marker RMS, faulty markers). "
        "Ctrl-C keeps the finished trials; --resume goes on from them. A trial that cannot be "
        "read or fitted is told and skipped (exit status 1).",
    )
    add_body_args(p)
    p.add_argument("static", help="static trial: the subject standing still (.trc or .c3d)")
    p.add_argument(
        "motion",
        help="trial to fit, frame by frame (.trc or .c3d); or a folder of trials, or a quoted "
        "glob pattern of them ('trials/*.trc')",
    )
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
        "--measure",
        action="append",
        default=[],
        metavar="NAME=METRES",
        help="a tape or caliper reading scaling takes beside the markers, e.g. --measure "
        "stature=1.78 (repeat it; stature, span, segment lengths and breadths as ANSUR II "
        "measures them); each read to --measure-sd",
    )
    p.add_argument(
        "--measure-sd",
        type=finite_float,
        default=None,
        metavar="METRES",
        help="the readings' standard deviation (default 0.005 m)",
    )
    p.add_argument(
        "--motion-frames",
        type=non_negative_int,
        metavar="K",
        help="register on K frames of the trials too (default 8; 0: the static trial alone)",
    )
    p.add_argument(
        "--no-velocity",
        action="store_true",
        help="no velocity term in the motion fits (each frame only starts from the last)",
    )
    p.add_argument(
        "--time",
        nargs=2,
        type=finite_float,
        default=None,
        metavar=("T0", "T1"),
        help="fit only the frames with T0 <= time <= T1 (s)",
    )
    p.add_argument(
        "--out",
        default=None,
        help="the fit's pose file (.npz, default fit.npz); for a folder or pattern of trials, "
        "the output folder (default fits/)",
    )
    optional = {"metavar": "FILE", "nargs": "?", "const": FLAG, "default": None}
    alone = "; for several trials give it alone: each trial's OUT/NAME"
    p.add_argument(
        "--png",
        **optional,
        help=f"PNG of a few fitted frames with their markers{alone}.png",
    )
    p.add_argument(
        "--curves",
        **optional,
        help="PNG of the fit over time: hip, knee, ankle angles and the marker error per "
        f"frame{alone}.curves.png",
    )
    p.add_argument(
        "--mot",
        **optional,
        help="OpenSim's coordinates of every frame (degrees and metres, OpenSim's names, signs "
        f"and zeros for --opensim-model){alone}.mot",
    )
    p.add_argument(
        "--angles",
        **optional,
        help=f"ISB joint angles of every frame, degrees, ISB's names and signs{alone}.angles.mot",
    )
    p.add_argument(
        "--opensim-model",
        default=None,
        metavar="MODEL",
        help="the OpenSim model --mot drives: its .osim or its marker set .xml, whose markers "
        "place its pelvis and torso frames (default: gait2354's Scale marker set)",
    )
    p.add_argument(
        "--trc", **optional, help=f"the model's markers of every frame (.trc){alone}.model.trc"
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="several trials: go on with an interrupted run's --out folder (same static "
        "trial, body and settings; its trials unchanged), fitting only the trials its "
        "trials.csv lacks; without it a trials.csv there is begun anew",
    )
    p.set_defaults(run=_mocap)


def _axes(text: str | None):
    """The lab axes named by --axes; None (not given) lets each file say its own."""
    from ..files._marker_trial import LAB_AXES

    if text is not None and text not in LAB_AXES:
        raise ValueError(f"--axes {text}: unknown lab axes; use one of {', '.join(LAB_AXES)}")
    return text


def several_trials(motion: str) -> bool:
    """Whether the command's second argument names several trials: a folder, or a glob
    pattern that is not itself a file's name."""
    return os.path.isdir(motion) or (glob.has_magic(motion) and not os.path.exists(motion))


_OUTPUTS = (
    ("--png", "png"),
    ("--curves", "curves"),
    ("--mot", "mot"),
    ("--angles", "angles"),
    ("--trc", "trc"),
)


def _mocap(args) -> int:
    if several_trials(args.motion):
        return _mocap_trials(args)
    if args.resume:
        raise ValueError(
            f"--resume: for a folder or a glob pattern of trials; {args.motion} is one trial"
        )
    for flag, attr in _OUTPUTS:
        if getattr(args, attr) is FLAG:
            suffix = ".mot" if attr in ("mot", "angles") else ".trc" if attr == "trc" else ".png"
            raise ValueError(f"{flag}: give a {suffix} file name (one trial: {args.motion})")
    args.out = "fit.npz" if args.out is None else args.out
    return _mocap_one(args)


def _mocap_trials(args) -> int:
    """A folder or glob pattern of trials: `fit_trials`, interrupts told as a clean stop."""
    from ..mocap._trials import SUMMARY, fit_trials, trial_files
    from ..runs._streaming import Interrupted, Interrupts, read_results

    out = "fits" if args.out is None else args.out
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValueError(f"--out {out}: is a file; with several trials --out names a folder")
    outputs = []
    for flag, attr in _OUTPUTS:
        value = getattr(args, attr)
        if value is not None and value is not FLAG:
            raise ValueError(
                f"{flag} {value}: with several trials give {flag} alone; each trial's file "
                f"goes into the --out folder ({out})"
            )
        if value is FLAG:
            outputs.append(attr)
    axes = _axes(args.axes)
    paths = trial_files(args.motion)
    body = body_from_args(args)
    summary = os.path.join(out, SUMMARY)
    with Interrupts() as signals:
        try:
            result = fit_trials(
                body,
                args.static,
                paths,
                args.markerset,
                out,
                resume=args.resume,
                tasks=args.tasks,
                keep_zeros=args.keep_zeros,
                axes=axes,
                prior=not args.no_prior,
                readings=readings(args),
                motion_frames=motion_frames(args),
                velocity=not args.no_velocity,
                time=tuple(args.time) if args.time is not None else None,
                outputs=outputs,
                opensim_model=args.opensim_model,
                progress=True,
                signals=signals,
            )
        except (Interrupted, KeyboardInterrupt) as e:
            # KeyboardInterrupt: a SIGINT the handler did not see (raised inside a JAX call).
            code = e.code if isinstance(e, Interrupted) else 130
            done = len(read_results(summary).ends) if os.path.exists(summary) else 0
            print(
                f"interrupted after {done} of {len(paths)} trials; {out} holds them; "
                "rerun with --resume",
                file=sys.stderr,
            )
            return code
    failed = f", {len(result.failed)} failed: {', '.join(result.failed)}" if result.failed else ""
    print(
        f"{len(result.fitted) + len(result.resumed)} of {result.total} trials done "
        f"({len(result.resumed)} by an earlier run){failed}; wrote {out} ({result.summary})"
    )
    return 1 if result.failed else 0


def _mocap_one(args) -> int:
    import jax

    from ..clouds._cloud_fit import FitStatus
    from ..files._marker_files import read_markers
    from ..files._opensim_files import read_ik_tasks
    from ..mocap._grades import grade_motion, grade_static, readings_report, registration_report
    from ..mocap._markerset import match_markers
    from ..mocap._motion_fit import fit_motion
    from ..mocap._static_fit import scale_and_register
    from ..mocap._trial_outputs import (
        load_any_markerset,
        picture,
        save_angles,
        save_coordinates,
        save_curves,
        save_fit,
        save_model_markers,
        save_scaled_body,
        scaled_body,
    )
    from ..mocap._trials import noted

    for flag, path, suffix in (
        ("--out", args.out, ".npz"),
        ("--png", args.png, ".png"),
        ("--curves", args.curves, ".png"),
        ("--mot", args.mot, ".mot"),
        ("--angles", args.angles, ".mot"),
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
    markerset = noted(print, load_any_markerset, args.markerset, body)

    t0 = time.perf_counter()
    measured = readings(args)
    k = motion_frames(args)
    settings = dict(prior=not args.no_prior, motion=motion, motion_frames=k, **measured)
    static_fit = noted(print, scale_and_register, body, static, markerset, **settings)
    jax.block_until_ready(static_fit)
    if measured:
        print(readings_report(static_fit.body, measured["measured"]))
    scale_s = time.perf_counter() - t0
    registered, trial = noted(print, match_markers, static_fit.markerset, motion)
    t0 = time.perf_counter()
    weights = None
    if tasks is not None:
        unused = [n for n in tasks if n not in registered.names]
        if unused:
            print(
                f"note: {args.tasks}: tasks for markers the fit lacks, ignored: {', '.join(unused)}"
            )
        weights = {n: w for n, w in tasks.items() if n in registered.names}
    out = noted(
        print,
        fit_motion,
        static_fit.body,
        registered,
        trial,
        start=static_fit.pose,
        weights=weights,
        scale=static_fit.marker_scale,
        velocity=not args.no_velocity,
        progress=True,
    )
    fit_s = time.perf_counter() - t0

    scaled = scaled_body(static_fit, body)
    out_path = Path(args.out)
    body_path = save_scaled_body(scaled, out_path.with_name(f"{out_path.stem}.body.json"))
    save_fit(out_path, scaled, static_fit, out, trial)
    per_marker = out.per_marker()

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
    if registration_report(static_fit):
        print(registration_report(static_fit))
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
    print("OpenSim's best practices:")
    for grade in grade_static(static_fit) + grade_motion(out):
        print(f"  {grade.line()}")
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
        name = f"{out_path.stem} OpenSim coordinates"
        save_coordinates(args.mot, out, static_fit, scaled, name, model=args.opensim_model)
        model = args.opensim_model or "gait2354"
        print(f"wrote {args.mot} (OpenSim's coordinates for {model}, degrees and metres)")
    if args.angles:
        save_angles(args.angles, out, scaled, name=f"{out_path.stem} ISB joint angles")
        print(f"wrote {args.angles} (ISB joint angles, degrees)")
    if args.trc:
        trc_axes = axes or "opensim"  # a TRC file is Y up unless --axes says otherwise
        save_model_markers(args.trc, out, trial, trc_axes)
        print(f"wrote {args.trc} (the model's markers, lab axes {trc_axes})")
    if args.png:
        picture(scaled, out, trial.positions, args.png, os.path.basename(args.motion))
        print(f"wrote {args.png}")
    if args.curves:
        save_curves(args.curves, out, scaled, title=os.path.basename(args.motion))
        print(f"wrote {args.curves} (joint angles and marker error over time)")
    return 1 if np.any(status == FitStatus.FAILED) else 0


def motion_frames(args) -> int:
    """--motion-frames (`MOTION_FRAMES` when not given)."""
    from ..mocap._motion_registration import MOTION_FRAMES

    return MOTION_FRAMES if args.motion_frames is None else args.motion_frames


def readings(args) -> dict:
    """`scale_and_register`'s readings from --measure NAME=METRES (repeated) and
    --measure-sd, as keyword arguments (empty: none)."""
    measured = {}
    for item in args.measure:
        name, _, value = item.partition("=")
        try:
            measured[name.strip()] = float(value)
        except ValueError:
            raise ValueError(
                f"--measure {item}: give NAME=METRES, e.g. --measure stature=1.78"
            ) from None
    if not measured:
        return {}
    sd = {} if args.measure_sd is None else {"measured_sd": args.measure_sd}
    return {"measured": measured, **sd}
