"""What the command line loads and says about its cache: the families load on first use,
the picture's imports run beside the solve, and the help tells where compiled solvers are
kept and how to clear them."""

import subprocess
import sys
import threading

import pytest

import diffbody
from diffbody.cli._args import prefetch
from diffbody.cli._main import main

LOADED = "import sys, diffbody; print(' '.join(sorted(sys.modules)))"


def test_import_diffbody_loads_no_family_and_no_matplotlib():
    run = subprocess.run(
        [sys.executable, "-c", LOADED], capture_output=True, text=True, timeout=300, check=True
    )
    loaded = set(run.stdout.split())
    for name in (
        "diffbody.images",
        "diffbody.mocap",
        "diffbody.clouds",
        "diffbody.ik",
        "diffbody.problem",
        "optimistix",
        "matplotlib",
    ):
        assert name not in loaded, name
    assert "diffbody._kinematics" in loaded  # the core is there at once


def test_every_public_name_and_family_resolves():
    for name in diffbody.__all__:
        assert getattr(diffbody, name) is not None, name
    assert set(diffbody.__all__) <= set(dir(diffbody))
    assert diffbody.ik.solve_reach is diffbody.solve_reach
    assert diffbody.cli.main is main
    with pytest.raises(AttributeError, match="no_such_name"):
        diffbody.no_such_name  # noqa: B018


def test_prefetch_imports_in_the_background_and_leaves_failures_to_the_caller():
    before = set(threading.enumerate())
    prefetch("no_such_module_for_diffbody", "json")
    for t in set(threading.enumerate()) - before:
        t.join(timeout=60)
    assert "no_such_module_for_diffbody" not in sys.modules


@pytest.mark.parametrize("argv", [["--help"], ["reach", "--help"]])
def test_help_says_where_the_compiled_solvers_are_kept(argv, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "$JAX_COMPILATION_CACHE_DIR" in text and "~/.cache/diffbody/jax" in text
    assert "Delete that folder to clear it" in text and "DIFFBODY_NO_CACHE=1" in text
