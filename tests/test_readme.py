"""The README and the user's guide run as written: every Python block, and every `diffbody`
command of the README (install, clone and virtual-environment lines are exempt, and so is
`pytest`, the command running this), in document order in one folder; and the README's
first screen says what diffbody does and how to start."""

import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
GUIDE = ROOT / "docs" / "guide.md"
BLOCK = re.compile(r"```(python|bash)\n(.*?)```", re.S)
EXEMPT = ("git clone", "cd ", "python -m venv", ". .venv", "pip install", "pytest")


def _commands(script: str) -> list[tuple[list[str], bool]]:
    """The `diffbody` commands of a bash block, each as (argv, whether it runs in the
    background: a line ending in `&`); anything else that is not exempt fails the test (a
    README command the test would silently skip)."""
    out = []
    for line in script.splitlines():
        line = line.split("  #")[0].strip()
        background = line.endswith(" &")
        line = line.removesuffix(" &")
        for part in filter(None, (p.strip() for p in line.split("&&"))):
            if part.startswith(EXEMPT):
                continue
            argv = shlex.split(part)
            assert argv[0] == "diffbody", f"README: a command the test cannot run: {part!r}"
            out.append((argv[1:], background))
    return out


def _view(argv: list[str], cwd: Path) -> None:
    """`diffbody view` serves until Ctrl-C: it must print its URL, answer it, and stop with
    exit status 0 on SIGINT."""
    import urllib.request

    log = cwd / "view.log"  # a file, not a pipe: a full pipe would block the server
    with log.open("w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "diffbody", *argv],
            cwd=cwd,
            stdout=out,
            stderr=subprocess.STDOUT,
            text=True,
        )
    try:
        url, deadline = None, time.monotonic() + 600
        while url is None and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
            url = re.search(r"open (http://\S+)", log.read_text())
        assert url, log.read_text()
        with urllib.request.urlopen(url.group(1), timeout=30) as page:
            assert page.status == 200
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 0, log.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.slow
def test_readme_runs_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}  # one session, as a reader runs the blocks in order
    ran = 0
    for kind, code in BLOCK.findall(README.read_text()):
        if kind == "python":
            with jax.enable_x64(False):  # as a user runs it: JAX's default float32
                exec(compile(code, str(README), "exec"), namespace)
            continue
        behind = []  # commands started with `&`, waited for after the next one
        for argv, background in _commands(code):
            if argv[0] == "view":
                _view(argv, tmp_path)
                ran += 1
                continue
            run = subprocess.Popen(
                [sys.executable, "-m", "diffbody", *argv],
                cwd=tmp_path,
                env=dict(os.environ),
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            ran += 1
            if background:
                behind.append((argv, run))
                continue
            for argv, run in [*behind, (argv, run)]:
                out, err = run.communicate(timeout=900)
                assert run.returncode == 0, (argv, out[-2000:], err[-2000:])
            behind = []
        assert not behind, "README: a command left in the background at the end of a block"
    assert ran >= 6
    for name in ("reach.pose.json", "reach.png", "pose.png", "reaches.gif", "body.xml"):
        assert (tmp_path / name).stat().st_size > 0, name


@pytest.mark.slow
def test_the_guide_runs_as_written(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", GUIDE.read_text(), flags=re.S)
    assert blocks
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for code in blocks:
        with jax.enable_x64(False):  # as a user runs it: JAX's default float32
            exec(compile(code, str(GUIDE), "exec"), namespace)
    assert (tmp_path / "pose.png").is_file()


def test_the_first_screen_says_what_and_how():
    """Within its first 40 lines the README says what a user can do (the five workflows and
    the viewer, one line each) and shows the install-and-run command; it stays short."""
    text = README.read_text()
    first = "\n".join(text.splitlines()[:40])
    for what in ("Reach", "Scale to a person", "motion capture", "sphere clouds", "2D video"):
        assert what in first, what
    assert "## Start" in first and "pip install . && diffbody reach" in first
    assert "python -m venv" in first
    assert len(text.encode()) < 15_000
