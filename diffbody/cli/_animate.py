"""The `diffbody animate` command: a pose file's sequence (or batch) drawn frame by frame to
a video or an animated GIF.

    diffbody animate walk.npz --out walk.mp4 --view left
"""

import time

from ._args import add_body_args, body_from_args, check_output, positive_float, view


def add_animate_command(sub) -> None:
    """Add the `animate` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser(
        "animate",
        help="draw a pose file's frames to a video (.mp4) or an animated GIF",
        description="Draws every frame of a pose file (diffbody.save_pose: a sequence, a "
        "batch or one pose) as shaded spheres seen by one fixed camera that frames them "
        "all, and writes them with imageio (pip install 'diffbody[view]').",
    )
    add_body_args(p)
    p.add_argument("file", help="pose file (.json or .npz, diffbody.save_pose)")
    p.add_argument("--out", required=True, help="animation to write: .mp4 or .gif")
    p.add_argument(
        "--view",
        type=view,
        default="perspective",
        help="front, back, left, right, top, perspective (default), or AZ,EL degrees",
    )
    p.add_argument(
        "--fps",
        type=positive_float,
        default=None,
        help="frames per second (default: the sequence's own rate, 10 for a batch)",
    )
    p.set_defaults(run=_animate)


def _animate(args) -> int:
    from ..files._pose_file import load_pose
    from ..viewer._animate import FORMATS, animate, frame_rate

    check_output("--out", args.out)
    if not args.out.lower().endswith(FORMATS):
        raise ValueError(f"--out {args.out}: give a file name ending in {' or '.join(FORMATS)}")
    body = body_from_args(args)
    record = load_pose(args.file, body)
    fps = args.fps or frame_rate(record.times, record.n_frames)
    t0 = time.perf_counter()
    path = animate(body, record, args.out, view=args.view, fps=fps)
    seconds = time.perf_counter() - t0
    print(
        f"wrote {path}: {record.n_frames} frames of {args.file} ({record.kind}) at "
        f"{fps:.3g} fps, in {seconds:.1f} s ({1000 * seconds / record.n_frames:.0f} ms "
        "per frame, compilation included)"
    )
    return 0
