"""The `diffbody export` command: the body as a MuJoCo MJCF model or a URDF robot,
optionally with a pose file's posture as its initial configuration."""

from ._args import add_body_args, body_from_args, check_output


def add_export_command(sub) -> None:
    """Add the `export` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser(
        "export",
        help="write the body as an MJCF (MuJoCo) or URDF model",
        description=(
            "Write the body as rigid links: MJCF with a free joint and a limited ball per "
            "segment (or the ZYZ hinges, singular at rest), or URDF with three hinges per "
            "segment whose singularity lies outside its limits. With --pose, the posture is "
            "the MJCF's first keyframe ('pose'; one per frame of a sequence); URDF has no "
            "initial state, so its joint values go to PATH's .joint_values.json beside it."
        ),
    )
    add_body_args(p)
    p.add_argument("--format", required=True, choices=("mjcf", "urdf"), help="file format")
    p.add_argument("--out", required=True, help="the file to write (e.g. body.xml, body.urdf)")
    p.add_argument("--pose", default=None, help="a pose file (diffbody.pose/1, .json or .npz)")
    p.add_argument(
        "--joints",
        choices=("ball", "hinges"),
        default="ball",
        help="MJCF joints: ball (default) or hinges (theta, phi, twist; singular at rest)",
    )
    p.set_defaults(run=_export)


def _read_pose(path: str, body):
    """The pose file's record, its errors naming the file."""
    from ..files import load_pose

    try:
        return load_pose(path, body)
    except (KeyError, TypeError, ValueError) as e:
        message = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
        if path not in str(message):
            message = f"{path}: {message}"
        raise ValueError(f"--pose {message}") from None


def _export(args) -> int:
    import json
    import warnings
    from pathlib import Path

    from ..export import export_mjcf, export_urdf, urdf_joint_values

    check_output("--out", args.out)
    if args.format == "urdf" and args.joints != "ball":
        raise ValueError("--joints hinges: only for --format mjcf (URDF always has hinges)")
    body = body_from_args(args)
    record = None if args.pose is None else _read_pose(args.pose, body)
    if args.format == "mjcf":
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            path = export_mjcf(
                body, args.out, joints=args.joints, pose=None if record is None else record.pose
            )
        for w in caught:
            print(f"warning: {w.message}")
        print(f"wrote {path}")
        if record is not None:
            print(f"keyframes: {record.n_frames} from {args.pose}, then standard_position")
        return 0
    path = export_urdf(body, args.out)
    print(f"wrote {path}")
    if record is not None:
        frames = [urdf_joint_values(body, record.frame(k)) for k in range(record.n_frames)]
        names = list(frames[0])
        sidecar = Path(path).with_suffix(".joint_values.json")
        sidecar.write_text(
            json.dumps(
                {
                    "urdf": Path(path).name,
                    "pose_file": str(args.pose),
                    "units": "rad",
                    "joint_names": names,
                    "positions": [[f[n] for n in names] for f in frames],
                },
                indent=1,
            )
        )
        print(f"wrote {sidecar}: joint values of {len(frames)} posture(s) (URDF has no initial")
        print("state: set the joints to them)")
    return 0
