"""The `diffbody` command line."""

import argparse
import sys


def _body(args):
    from ._loading import load_body

    return load_body(args.body, variant=args.variant)


def _summary(body) -> str:
    import jax.numpy as jnp

    from ._kinematics import forward

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
    from ._render import render

    body = _body(args)
    print(_summary(body))
    views = [v if "," not in v else tuple(float(x) for x in v.split(",")) for v in args.view]
    path = render(
        body,
        body.rest_pose(),
        args.out,
        views,
        features=args.features,
        skeleton=args.skeleton,
        title=f"diffbody {body.name}: standard position",
    )
    print(f"wrote {path}")
    return 0


def _info(args) -> int:
    body = _body(args)
    print(_summary(body))
    if args.names:
        print("segments:", ", ".join(body.segment_names))
        print("joints:", ", ".join(body.joint_names))
        print("features:", ", ".join(body.feature_names))
    return 0


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

    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except (ValueError, KeyError, FileNotFoundError) as e:
        print(f"diffbody: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
