"""What the `diffbody` commands share: argparse types, the body and solver options, checks
made before any loading or solving, and the persistent compilation cache."""

import argparse
import math
import os

CACHE_HELP = """\
compiled solvers: diffbody keeps what it compiles in JAX's persistent compilation cache (and
its solve programs exported beside it), so that a repeated command reads it back instead of
tracing and compiling again: the folder $JAX_COMPILATION_CACHE_DIR when set, else
$XDG_CACHE_HOME/diffbody/jax (~/.cache/diffbody/jax). Delete that folder to clear it (it is
refilled as needed); DIFFBODY_NO_CACHE=1 leaves it off."""


def prefetch(*modules: str) -> None:
    """Import modules in a background thread while the caller goes on: the picture's
    matplotlib (about 0.5 s of imports) loads while XLA compiles or reads back the solver,
    which release Python's lock. Called once the solver's own imports are done, so the two
    threads never import the same module; a failure here is left for the real import to
    report."""
    import importlib
    import threading

    def load() -> None:
        for name in modules:
            try:
                importlib.import_module(name)
            except Exception:  # the drawing's own import raises it where it can be reported
                return

    threading.Thread(target=load, name="diffbody-prefetch", daemon=True).start()


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer (1, 2, ...), got {text!r}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0 (an index, a count)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}")
    return value


def finite_float(text: str) -> float:
    """argparse type: a finite number (nan and inf parse as floats but are no position)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number in metres, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def view(text: str):
    """argparse type: a named view or "AZ,EL" (camera azimuth and elevation, degrees)."""
    from .._render import VIEWS

    if text in VIEWS:
        return text
    parts = text.split(",")
    try:
        az, el = (float(x) for x in parts)
    except ValueError:
        az = el = math.nan
    if not (math.isfinite(az) and math.isfinite(el)):
        raise argparse.ArgumentTypeError(
            f"unknown view {text!r}; use one of {', '.join(VIEWS)} "
            "or AZ,EL (camera azimuth and elevation in degrees, e.g. 30,15)"
        )
    return (az, el)


def add_body_args(p) -> None:
    """Add --variant and --body, the body a command works on, to a sub-parser."""
    p.add_argument("--variant", default="male50", help="embedded body: male50 or female50")
    p.add_argument("--body", default=None, help="a body JSON file instead (data/SCHEMA.md)")


def add_solver_args(p) -> None:
    """Add --no-spine, --segments and --starts, the reach solver's options, to a sub-parser."""
    p.add_argument("--no-spine", action="store_true", help="keep the spine at rest")
    p.add_argument(
        "--segments",
        nargs="+",
        default=None,
        help="only these segments move (names, on the effector's chain)",
    )
    p.add_argument("--starts", type=positive_int, default=8, help="most solver starts (default 8)")


def check_pose_output(option: str, path: str | None) -> None:
    """Refuse a pose file name without a pose file's suffix (.json or .npz) before solving."""
    if path is not None and not path.lower().endswith((".json", ".npz")):
        raise ValueError(f"{option} {path}: a pose file ends in .json or .npz")


def check_output(option: str, path: str | None) -> None:
    """Refuse an output file that cannot be written, before any loading or solving, so a
    typo in a folder name does not cost a whole solve."""
    if path is None:
        return
    if not path:
        raise ValueError(f"{option}: empty file name")
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise ValueError(f"{option} {path}: is a folder; give a file name")
    if not os.path.exists(folder):
        raise ValueError(f"{option} {path}: folder {folder} does not exist")
    if not os.path.isdir(folder):
        raise ValueError(f"{option} {path}: {folder} is not a folder")
    if not os.access(folder, os.W_OK):
        raise ValueError(f"{option} {path}: cannot write in folder {folder}")


def body_from_args(args):
    """The body that --body (a file) or else --variant (an embedded body) names."""
    from ..files._body_file import load_body

    return load_body(args.body, variant=args.variant)


def check_names(body, effectors: list[str], segments: list[str] | None) -> None:
    """Unknown effector or segment names, reported with the option before any solve."""
    from ..problem._targets import Target, resolve_targets

    hint = " (diffbody info --names lists them)"
    try:
        resolve_targets(body, [Target.position(e, [0.0, 0.0, 0.0]) for e in effectors])
    except KeyError as e:
        raise KeyError(f"--effector: {e.args[0]}{hint}") from None
    for name in segments or []:
        try:
            body.segment_index(name)
        except KeyError as e:
            raise KeyError(f"--segments: {e.args[0]}{hint}") from None


def effector_chain(body, effectors: list[str]) -> list[str]:
    """The segments whose joints move the effectors, top-down (every segment for the center
    of gravity or a body re-rooted elsewhere); the whole body's placement never moves in a
    reach, so it is not among them."""
    from ..problem._targets import point_index
    from ..problem._unknowns import segments_on_path

    on = segments_on_path(body, [point_index(body, e) for e in effectors])
    top_down = sorted(on - {0}, key=lambda s: (len(body.path_to_top(s)), s))
    return [body.segment_names[s] for s in top_down]


def check_segments(body, effectors: list[str], segments: list[str] | None) -> str:
    """--segments against the effectors' chain: a ValueError naming both when none of them
    is on it; else a note naming those off it (they cannot move an effector and are
    ignored), or "" when all are on it."""
    if not segments:
        return ""
    chain = effector_chain(body, effectors)
    off = [s for s in segments if s not in chain]
    which = " ".join(f"--effector {e}" for e in effectors)
    if len(off) == len(segments):
        raise ValueError(
            f"--segments {' '.join(segments)}: none of them moves {which}; the segments on "
            f"{'its chain' if len(effectors) == 1 else 'their chains'} are {', '.join(chain)}; "
            "name some of those, or leave --segments out to let the whole chain move"
        )
    if not off:
        return ""
    return f"note: --segments {' '.join(off)}: not on the chain of {which}, ignored"
