"""The `diffbody fit` command: the body's dimensions and pose fitted to a measured sphere cloud
(.npz), the fitted body and its pose written."""

import dataclasses
import os

from ._args import add_body_args, body_from_args, check_output


def add_fit_command(sub) -> None:
    """Add the `fit` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser(
        "fit",
        help="fit the body's dimensions and pose to a measured sphere cloud (.npz)",
        description="The cloud: numpy.savez(path, centers=(m, 3), radii=(m,)) in metres, "
        "optionally correspondences=(m,) model sphere indices (-1 for none).",
    )
    add_body_args(p)
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


def _fit(args) -> int:

    import numpy as np

    from ..clouds._annealing import INLIER_DISTANCE, LANDED_COVERED, LANDED_INLIERS
    from ..clouds._cloud_fit import FitStatus, fit_spheres
    from ..files._cloud_file import read_cloud
    from ..files._saving import save_body

    check_output("--out", args.out)
    check_output("--png", args.png)
    body = body_from_args(args)
    centers, radii, match = read_cloud(args.cloud)
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
    runner_up = float(out.runner_up)
    other = f", the next start's {runner_up:.3f}" if np.isfinite(runner_up) else ""
    print(
        f"score {float(out.score):.3f} (0: every sphere on its place){other}; "
        f"{100 * float(out.covered):.0f} % of the model's spheres covered"
    )
    landed = bool(out.landed)
    if not landed:
        print(
            f"did not land: it needs {100 * LANDED_INLIERS:.0f} % of the spheres inliers and "
            f"{100 * LANDED_COVERED:.0f} % of the model's spheres covered (the cloud may not "
            "be a body, or no start found a posture near it; correspondences help)"
        )
    from ..anthropometry._scaling import SCALE_GROUPS
    from ..files._pose_file import save_pose

    print("scale group        axial  radial")
    for name, a, r in zip(SCALE_GROUPS, np.asarray(out.axial), np.asarray(out.radial)):
        print(f"  {name:<15} {a:7.4f} {r:7.4f}")
    path = save_body(fitted, args.out)
    pose_path = save_pose(
        path.with_name(f"{path.stem}.pose.json"),
        fitted,
        out.pose,
        status=status,
        residuals={"spheres": out.residuals},
        scale={
            "groups": list(SCALE_GROUPS),
            "axial": out.axial,
            "radial": out.radial,
        },
        overlays={"cloud": {"centers": centers, "radii": radii, "inliers": inliers}},
        extra={
            "cloud": args.cloud,
            "landed": landed,
            "score": float(out.score),
            "runner_up": runner_up if np.isfinite(runner_up) else None,
            "covered": float(out.covered),
            "steps": int(out.steps),
        },
    )
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
