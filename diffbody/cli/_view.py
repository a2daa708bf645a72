"""The `diffbody view` command: a pose file in the interactive 3D viewer, served until
Ctrl-C."""

from time import sleep

from ._args import add_body_args, body_from_args, non_negative_int


def add_view_command(sub) -> None:
    """Add the `view` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser(
        "view",
        help="open a pose file (a pose, a sequence or a batch) in the browser's 3D viewer",
        description="Serve the body in a saved pose, sequence or batch as an interactive 3D "
        "page (viser; pip install 'diffbody[view]'), with a time slider, the file's markers, "
        "cloud and targets, and the joint angles; runs until Ctrl-C.",
    )
    p.add_argument("file", help="a pose file (diffbody.save_pose, .json or .npz)")
    add_body_args(p)
    p.add_argument(
        "--port",
        type=non_negative_int,
        default=8080,
        help="port to serve on (default 8080; taken: the next free one; 0: any free one)",
    )
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="interface to serve on (default 127.0.0.1; 0.0.0.0 for other machines)",
    )
    p.set_defaults(run=_view)


def _view(args) -> int:
    from ..files._pose_file import load_pose

    body = body_from_args(args)
    record = load_pose(args.file, body)  # a missing or foreign file is reported before serving
    from ..viewer import view

    try:
        viewer = view(body, record, port=args.port, host=args.host, title=args.file)
    except ImportError as e:  # viser missing: the command's error, not a traceback
        raise ValueError(str(e)) from None
    frames = "" if record.kind == "pose" else f", {record.n_frames} frames ({record.kind})"
    print(f"{args.file}{frames}: open {viewer.url} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
    return 0
