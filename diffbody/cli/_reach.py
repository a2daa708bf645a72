"""The `diffbody reach` command: one effector to one target, the posture printed and
optionally written as a pose file and drawn."""

import argparse

from ._args import (
    CACHE_HELP,
    add_body_args,
    add_solver_args,
    body_from_args,
    check_names,
    check_output,
    check_pose_output,
    check_segments,
    finite_float,
    prefetch,
)


def add_reach_command(sub) -> None:
    """Add the `reach` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser(
        "reach",
        help="reach one target with an effector (inverse kinematics)",
        epilog=CACHE_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_body_args(p)
    p.add_argument("--effector", required=True, help="joint, feature or center_of_gravity")
    p.add_argument("--target", nargs=3, type=finite_float, required=True, metavar=("X", "Y", "Z"))
    p.add_argument("--out", default=None, help="pose file to write (.json or .npz)")
    p.add_argument("--png", default=None, help="PNG of the pose to write")
    add_solver_args(p)
    p.set_defaults(run=_reach)


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
    import jax
    import numpy as np

    from ..ik._reach import ReachStatus, solve_reach
    from ..problem._targets import Target

    check_output("--out", args.out)
    check_pose_output("--out", args.out)
    check_output("--png", args.png)
    body = body_from_args(args)
    check_names(body, [args.effector], args.segments)
    note = check_segments(body, [args.effector], args.segments)
    if note:
        print(note)
    target = np.asarray(args.target, float)
    if args.png:
        prefetch("matplotlib.figure", "matplotlib.backends.backend_agg")
    out = solve_reach(
        body,
        [Target.position(args.effector, target)],
        spine=not args.no_spine,
        segments=args.segments,
        starts=args.starts,
    )
    # One transfer to the host: indexing device arrays one by one compiles a small program
    # for each (tens of milliseconds apiece in a fresh process).
    out = jax.device_get(out)
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
        from ..files._pose_file import save_pose

        save_pose(
            args.out,
            body,
            out.pose,
            status=ReachStatus(int(out.status)),
            residuals={"targets": out.residuals},
            overlays={"targets": {"names": [args.effector], "points": [target]}},
            extra={
                "effector": args.effector,
                "target": target,
                "reached": out.reached,
                "steps": int(out.steps),
            },
        )
        print(f"wrote {args.out} (a pose file: diffbody view, diffbody render --pose)")
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
