"""The `diffbody render` and `diffbody info` commands: the body in its standard position, drawn
to a PNG or summarised."""

from ._args import add_body_args, body_from_args, check_output, view


def add_render_command(sub) -> None:
    """Add the `render` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser("render", help="draw the body in its standard position to a PNG")
    add_body_args(p)
    p.add_argument("--out", default="body.png", help="PNG to write (default body.png)")
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
