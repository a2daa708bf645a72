"""The `diffbody scale` command: the default body scaled to given measurements, the others
following the ANSUR II population, written as a body file."""

import dataclasses

from ._args import check_output, positive_float


def add_scale_command(sub) -> None:
    """Add the `scale` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser(
        "scale",
        help="scale the default body to measurements (metres, weight in kg)",
        description="Measurements not given follow the ANSUR II population given those that are.",
    )
    p.add_argument("--sex", required=True, choices=["male", "female"])
    p.add_argument("--out", required=True, help="body JSON to write (data/SCHEMA.md)")
    p.add_argument("--png", default=None, help="PNG of the scaled body to write")
    p.add_argument("--name", default=None, help="the body's name in the file")
    p.add_argument("--weight", dest="weightkg", type=positive_float, help="kg")
    from ..anthropometry._measurements import MEASUREMENTS

    for name, m in MEASUREMENTS.items():
        if name != "weightkg":
            p.add_argument(f"--{name}", type=positive_float, metavar="M", help=m.definition)
    p.set_defaults(run=_scale)


def _scale(args) -> int:
    from ..anthropometry._measurements import MEASUREMENT_NAMES, measurements
    from ..anthropometry._scale_to import scale_to
    from ..files._saving import save_body

    check_output("--out", args.out)
    check_output("--png", args.png)
    given = {n: getattr(args, n) for n in MEASUREMENT_NAMES if getattr(args, n) is not None}
    body = scale_to(None, given, sex=args.sex)
    body = dataclasses.replace(body, name=args.name or f"{args.sex}-scaled")
    path = save_body(body, args.out)
    print(f"wrote {path}" + (f" and {path.stem}.spine.json" if body.spine else ""))
    print("measurement                      value  (given *)")
    for name, value in measurements(body).items():
        unit = "kg" if name == "weightkg" else "m"
        print(f"  {name:<30} {value:8.4f} {unit}{' *' if name in given else ''}")
    if args.png:
        from .._render import render

        render(body, body.rest_pose(), args.png, ["front", "left"], title=f"diffbody {body.name}")
        print(f"wrote {args.png}")
    return 0
