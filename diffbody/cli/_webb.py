"""`diffbody webb`: lengths and 3D joints of a jointed figure from its 2D joint positions in
a sequence of images (seed 003, Webb's static analysis, with reflections chosen by
continuity and a joint least-squares refinement).

Input files:

- points CSV: one row per frame; a header names the columns ``<joint>.u`` and
  ``<joint>.v`` for every joint of the skeleton (any order; other columns are refused);
  pixels from the principal point, v pointing down (or raw pixel coordinates with
  ``--principal-point CX CY``);
- root-depth CSV: one number per row (an optional header line), the reference joint's
  depth in metres in each frame: as many rows as the points file;
- skeleton JSON (``--skeleton``, default the body's major joints): see
  `diffbody.read_joint_tree`;
- anchor JSON (``--anchor``, with ``--anchor-frame N``, default 0): the reflection of parts
  in frame N, an object ``{"<start>-><end>": "near" or "far"}`` keyed by the part names of
  the output's ``lengths_m`` (0 and 1, the output's reflection codes, are taken too). Near:
  the part's ending joint is the nearer of the two points on its image ray at the part's
  length from its starting joint (the part points toward the camera); far: the farther one.
  Parts left out are left to continuity. Without an anchor every part's mirror image is as
  smooth as the truth, and the reflections match it about half the time.

Output: ``--out`` JSON with the lengths per part (refined, and Webb's lower bounds), the 3D
joints per frame (camera frame: x right, y down, z along the optical axis, m), the
reflection of every part in every frame (0 near, 1 far) and the refinement's status;
``--png`` the recovered skeleton over the image points.
"""

import argparse
import math
from pathlib import Path

from ._args import check_output, positive_float


def _pixel(text: str) -> float:
    """argparse type: a finite number of pixels."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number of pixels, got {text!r}")
    return value


def _anchor(args, tree, n_frames: int):
    """--anchor's codes (None without it) and --anchor-frame as a frame index (0..T-1)."""
    if args.anchor is None:
        if args.anchor_frame is not None:
            raise ValueError(
                f"--anchor-frame {args.anchor_frame}: needs --anchor FILE, the reflections "
                "of the parts in that frame"
            )
        return None, 0
    frame = 0 if args.anchor_frame is None else args.anchor_frame
    if not -n_frames <= frame < n_frames:
        raise ValueError(
            f"--anchor-frame {frame}: {args.points} has {n_frames} frames; give 0 to "
            f"{n_frames - 1} (or -1 for the last)"
        )
    from ..files._webb_files import read_anchor

    return read_anchor(args.anchor, tree.part_names), frame % n_frames


def _webb(args) -> int:
    import json

    import numpy as np

    from .._statuses import FitStatus
    from ..files._webb_files import read_depths, read_points
    from ..images._joint_tree import default_joint_tree, read_joint_tree
    from ..images._lifting import LiftOptions, lift
    from ..images._reflections import choose_reflections

    check_output("--out", args.out)
    check_output("--png", args.png)
    tree = read_joint_tree(args.skeleton) if args.skeleton else default_joint_tree()
    uv = read_points(args.points, tree.names)
    if args.principal_point is not None:
        uv = uv - np.asarray(args.principal_point)
    depth = read_depths(args.root_depth, len(uv))
    if len(uv) < 3:
        raise ValueError(f"{args.points}: {len(uv)} frames; the analysis needs at least 3")
    anchor, frame = _anchor(args, tree, len(uv))
    if args.no_refine:
        choice = choose_reflections(tree, uv, depth, args.focal, anchor=anchor, anchor_frame=frame)
        lifted = None
    else:
        options = LiftOptions(pixel_sigma=args.pixel_sigma)
        choice, lifted = lift(
            tree, uv, depth, args.focal, anchor=anchor, anchor_frame=frame, options=options
        )
    webb_lengths = np.asarray(choice.lengths)
    if lifted is None:
        lengths, joints, status = webb_lengths, np.asarray(choice.joints), None
    else:
        lengths, joints = np.asarray(lifted.lengths), np.asarray(lifted.joints)
        status = FitStatus(int(lifted.status))
    print(f"{len(uv)} frames, {tree.n_parts} parts, reference {tree.names[tree.root]!r}")
    if anchor is not None:
        known = f"{int((anchor >= 0).sum())} of {tree.n_parts}"
        print(f"anchor: the reflections of {known} parts in frame {frame} ({args.anchor})")
    print(f"{'part':<34} {'Webb (m)':>9} {'refined (m)':>12}")
    for k, name in enumerate(tree.part_names):
        refined = "" if args.no_refine else f"{float(lifted.lengths[k]):12.4f}"
        print(f"{name:<34} {webb_lengths[k]:9.4f} {refined}")
    if status is not None:
        print(
            f"refinement: {status.describe()} after {int(lifted.steps)} steps, "
            f"reprojection RMS {float(lifted.reprojection_rms):.2f} px"
        )
    if args.out:
        doc = {
            "skeleton": [
                {"name": n, "parent": None if p == -1 else tree.names[p]}
                for n, p in zip(tree.names, tree.parents)
            ],
            "parts": list(tree.part_names),
            "focal_px": args.focal,
            "frames": len(uv),
            "lengths_m": {n: float(v) for n, v in zip(tree.part_names, lengths)},
            "webb_lengths_m": {n: float(v) for n, v in zip(tree.part_names, webb_lengths)},
            "joints_m": np.round(joints, 6).tolist(),
            "joints_frame": "camera: x right, y down, z along the optical axis",
            "reflections": np.asarray(choice.reflections).tolist(),
            "reflection_codes": {"0": "near (toward the camera)", "1": "far"},
            "anchor": None
            if anchor is None
            else {
                "frame": frame,
                "reflections": {
                    n: ("near", "far")[a] for n, a in zip(tree.part_names, anchor) if a >= 0
                },
            },
            "refined": not args.no_refine,
            "status": None if status is None else status.name.lower(),
            "reprojection_rms_px": None if args.no_refine else float(lifted.reprojection_rms),
        }
        with open(args.out, "w") as f:
            json.dump(doc, f, indent=1)
        print(f"wrote {args.out}")
    if args.png:
        from ..images._sequence_plots import draw_lifting

        draw_lifting(
            tree,
            uv,
            joints,
            args.focal,
            args.png,
            title=f"diffbody webb: {Path(args.points).name}"
            + ("" if args.no_refine else " (refined)"),
        )
        print(f"wrote {args.png}")
    return 0


def add_webb_command(sub) -> None:
    """Add the `webb` subcommand to the argparse subparsers of `diffbody.cli.main`."""
    p = sub.add_parser(
        "webb",
        help="lengths and 3D joints from 2D joint positions in an image sequence (seed 003)",
        description=(
            "Webb's static analysis: rigid-part lengths and 3D joints from the image points of "
            "every joint in every frame, the focal length and the reference joint's depth; "
            "reflections chosen by continuity, then refined by least squares. Points CSV: a "
            "header <joint>.u,<joint>.v for every joint, one row per frame, pixels from the "
            "principal point, v down."
        ),
    )
    p.add_argument(
        "points", help="CSV of image points: <joint>.u,<joint>.v per joint, a row per frame"
    )
    p.add_argument("--focal", type=positive_float, required=True, help="focal length (px)")
    p.add_argument(
        "--root-depth", required=True, help="CSV: the reference joint's depth (m), a row per frame"
    )
    p.add_argument(
        "--skeleton", default=None, help="skeleton JSON (default: the body's major joints)"
    )
    p.add_argument(
        "--principal-point",
        nargs=2,
        type=_pixel,
        default=None,
        metavar=("CX", "CY"),
        help="subtract this from the points (raw pixel coordinates)",
    )
    p.add_argument(
        "--pixel-sigma", type=positive_float, default=1.0, help="image noise (px, default 1)"
    )
    p.add_argument(
        "--anchor",
        default=None,
        metavar="FILE",
        help='JSON of part reflections in the anchor frame: {"<start>-><end>": "near" or "far"}',
    )
    p.add_argument(
        "--anchor-frame",
        type=int,
        default=None,
        metavar="N",
        help="the frame --anchor describes (default 0, the first; -1 the last)",
    )
    p.add_argument("--no-refine", action="store_true", help="Webb's estimate only")
    p.add_argument("--out", default="lengths.json", help="JSON to write (default lengths.json)")
    p.add_argument("--png", default=None, help="PNG of the skeleton over the image points")
    p.set_defaults(run=_webb)
