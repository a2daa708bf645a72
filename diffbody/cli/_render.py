"""The `diffbody render` and `diffbody info` commands: the body in its standard position or in
a saved pose, drawn to a PNG, or summarised."""

from ._args import add_body_args, body_from_args, check_output, non_negative_int, view

MARKER_RADIUS = 0.012  # m, a measured marker drawn as an outline
TARGET_RADIUS = 0.02  # m, a reach target


def add_render_command(sub) -> None:
    """Add the `render` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser(
        "render", help="draw the body in its standard position, or a saved pose, to a PNG"
    )
    add_body_args(p)
    p.add_argument("--out", default="body.png", help="PNG to write (default body.png)")
    p.add_argument("--pose", default=None, help="a pose file to draw (diffbody.save_pose)")
    p.add_argument(
        "--frame",
        type=non_negative_int,
        default=0,
        help="frame of a sequence or row of a batch to draw (default 0)",
    )
    p.add_argument(
        "--view",
        nargs="+",
        type=view,
        default=["front", "left", "perspective"],
        help="views: front, back, left, right, top, perspective, or AZ,EL degrees",
    )
    p.add_argument("--features", action="store_true", help="mark the named features")
    p.add_argument("--skeleton", action="store_true", help="draw the segment axes")
    p.set_defaults(run=_render)


def add_info_command(sub) -> None:
    """Add the `info` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser("info", help="summarise a body")
    add_body_args(p)
    p.add_argument("--names", action="store_true", help="list segments, joints and features")
    p.set_defaults(run=_info)


def _summary(body) -> str:
    """Two lines: the body's counts, and its stature, mass and center of gravity at rest."""
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


def _overlay(record, k: int):
    """(centers, radii, inliers) of what the pose file draws over frame k: its sphere cloud,
    measured markers and reach targets (gaps left out); None when it has none."""
    import numpy as np

    parts = []
    cloud = record.overlays.get("cloud")
    if cloud:
        inliers = cloud.get("inliers")
        inliers = np.ones(len(cloud["radii"]), bool) if inliers is None else inliers
        parts.append((cloud["centers"], cloud["radii"], inliers))
    for name, radius in (("markers", MARKER_RADIUS), ("targets", TARGET_RADIUS)):
        group = record.overlays.get(name)
        if not group:
            continue
        points = np.asarray(group.get("positions", group.get("points")), float)
        points = points[k] if points.ndim == 3 else points
        points = points[np.all(np.isfinite(points), axis=1)]
        parts.append((points, np.full(len(points), radius), np.ones(len(points), bool)))
    if not parts:
        return None
    return tuple(np.concatenate([np.asarray(p[i], float) for p in parts]) for i in range(3))


def _render(args) -> int:
    from .._render import render

    check_output("--out", args.out)
    body = body_from_args(args)
    print(_summary(body))
    pose, cloud, title = body.rest_pose(), None, f"diffbody {body.name}: standard position"
    if args.pose:
        from ..files._pose_file import load_pose

        record = load_pose(args.pose, body)
        if args.frame >= record.n_frames:
            raise ValueError(
                f"--frame {args.frame}: {args.pose} holds {record.n_frames} frame(s), "
                f"0 to {record.n_frames - 1}"
            )
        pose, cloud = record.frame(args.frame), _overlay(record, args.frame)
        at = "" if record.kind == "pose" else f", frame {args.frame} of {record.n_frames}"
        title = f"diffbody {body.name}: {args.pose}{at}"
    path = render(
        body,
        pose,
        args.out,
        args.view,
        features=args.features,
        skeleton=args.skeleton,
        title=title,
        cloud=cloud,
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
