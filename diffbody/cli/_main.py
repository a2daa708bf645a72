"""The `diffbody` command line: the parser built from every command's module, the dispatch
and the error message."""

import argparse
import contextlib
import os
import signal
import sys
from typing import NoReturn

from .._programs import keep_compiled
from ._animate import add_animate_command
from ._args import CACHE_HELP
from ._batch import add_batch_command
from ._export import add_export_command
from ._fit import add_fit_command
from ._mocap import add_mocap_command
from ._reach import add_reach_command
from ._render import add_info_command, add_render_command
from ._scale import add_scale_command
from ._view import add_view_command
from ._webb import add_webb_command

# The commands that solve: those whose compiled functions the persistent cache keeps.
COMPILING = ("reach", "batch", "scale", "fit", "mocap", "webb", "animate", "view", "export")
# The exit statuses of a command stopped by SIGINT or SIGTERM (128 + the signal's number).
INTERRUPTED = (128 + signal.SIGINT, 128 + signal.SIGTERM)


def main(argv: list[str] | None = None) -> int:
    """Run the `diffbody` command line on argv (default sys.argv[1:]); the exit status."""
    parser = argparse.ArgumentParser(
        prog="diffbody",
        description="Differentiable kinematics of sphere-skinned bodies.",
        epilog=CACHE_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for add_command in (
        add_render_command,
        add_info_command,
        add_reach_command,
        add_batch_command,
        add_scale_command,
        add_fit_command,
        add_mocap_command,
        add_webb_command,
        add_view_command,
        add_export_command,
        add_animate_command,
    ):
        add_command(sub)

    args = parser.parse_args(argv)
    if argv is None and args.command in COMPILING:
        keep_compiled()
    code = _run(args)
    if argv is None and code in INTERRUPTED:
        exit_at_once(code)
    return code


def _run(args) -> int:
    """Run the parsed command; its exit status, an error told in one line."""
    try:
        return args.run(args)
    except KeyError as e:  # its str() would quote the message
        message = e.args[0] if e.args else repr(e)
    except OSError as e:  # FileNotFoundError, IsADirectoryError, PermissionError, ...
        message = f"{e.filename}: {e.strerror}" if e.filename and e.strerror else str(e)
    except ValueError as e:  # BodyFileError, a malformed CSV, UnicodeDecodeError, ...
        message = str(e)
    except KeyboardInterrupt:  # Ctrl-C: a stop, not a crash (batch and mocap say more)
        print("diffbody: interrupted", file=sys.stderr)
        return 130
    print(f"diffbody: error: {message}", file=sys.stderr)
    return 2


def exit_at_once(code: int) -> NoReturn:
    """End the process of a command stopped by a signal, its output flushed, without the
    interpreter's teardown.

    A signal stops the main thread inside jaxlib's `compile_and_load` (which checks for
    signals while it waits), not the compile, which goes on in the XLA client's thread pool.
    The teardown's last garbage collection frees that client: ~PjRtClient waits for its pool,
    and the compile, once done, builds its executable on the client being freed
    (SingleDeviceSharding::Create calls a null address): the process dies of SIGSEGV (exit
    status 139), up to a minute after its clean stop was told. What the run keeps is on the
    disk already (each chunk and trial is fsynced when written), so skipping the teardown
    loses nothing; jax.distributed is shut down as JAX's atexit would, so that the other
    processes are not left waiting.
    """
    if "jax" in sys.modules:
        sys.modules["jax"].distributed.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError):  # a closed pipe: nothing more can be told
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    sys.exit(main())
