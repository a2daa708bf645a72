"""The benchmarks and the README's figures: every benchmark runs (`--quick`, a smoke run with
small sizes and no peers, on the suite's compilation cache) and writes a results file the
README's tables render from; every table in the README is what `benchmarks/render_readme.py`
renders from the committed results files, and says which commit it measured."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import (  # noqa: E402
    GOAL_COLD_COMPILE_S,
    cold_compile_goal,
    fresh_process,
)
from render_readme import (  # noqa: E402
    MARKER,
    PAGES,
    caption,
    changed_since,
    goals_table,
    markdown,
    render_one,
)
from results import RESULTS, load  # noqa: E402

# Tables that only a full run fills (peers are not run by --quick).
FULL_RUN_ONLY = {("ik", "peers")}
BENCHMARKS = (
    "fk",
    "spine",
    "ik",
    "solvers",
    "anthropometry",
    "mocap",
    "webb",
    "lifting_prior",
    "_sphere_cloud",
    "collision",
    "batch",
    "startup",
)


def readme_tables() -> list[tuple[str, str, str]]:
    """(results name, table, the text between the markers) of each table of the pages."""
    return [
        (m["name"], m["table"], m["body"])
        for page in PAGES
        for m in MARKER.finditer(page.read_text())
    ]


@pytest.mark.slow
@pytest.mark.parametrize("script", BENCHMARKS)
def test_benchmark_runs_and_writes_what_the_readme_shows(script, tmp_path):
    env = dict(os.environ)  # the suite's compilation cache and XLA flags (conftest.py)
    run = subprocess.run(
        [sys.executable, f"benchmarks/{script}.py", "--quick", "--out", str(tmp_path)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    (path,) = tmp_path.glob("*.json")
    record = load(path)
    assert record["quick"] and record["machine"] and record["versions"]
    assert len(record["commit"]) == 40 and isinstance(record["clean"], bool)
    name = path.stem
    for table in {t for n, t, _ in readme_tables() if n == name}:
        if (name, table) in FULL_RUN_ONLY:
            continue
        body = record["goals"] if table == "goals" else record["tables"][table]["rows"]
        assert body, f"{script} --quick wrote no rows for the README's table {table!r}"
    if name == "lifting_prior":
        # Regression: the goals once took the figures of the easier row beside them (the
        # true reflections in every frame) instead of the pipeline's.
        rows = record["tables"]["prior"]["rows"]
        pipeline = [r[2] for r in rows if r[1] != "none" and "true reflections" not in r[0]]
        lengths = [g["measured"] for g in record["goals"] if g["figure"].startswith("length")]
        assert lengths == pipeline


def test_every_results_file_is_a_full_run_shown_in_the_readme():
    shown = {n for n, _, _ in readme_tables()}
    files = {p.stem for p in RESULTS.glob("*.json")}
    assert files == shown, (files, shown)
    for name in files:
        record = load(RESULTS / f"{name}.json")
        assert not record["quick"], f"{name}.json is a --quick run"
        assert len(record["commit"]) == 40 and isinstance(record["clean"], bool)


@pytest.mark.parametrize(("name", "table"), [(n, t) for n, t, _ in readme_tables()])
def test_readme_table_is_rendered_from_its_results_file(name, table):
    """The README's text is the renderer's: figures from the file, and a caption naming the
    commit, saying whether the tree was clean and whether the code changed since (where git
    cannot tell, a shallow clone, either caption)."""
    (shown,) = [body for n, t, body in readme_tables() if (n, t) == (name, table)]
    record = load(RESULTS / f"{name}.json")
    stale = changed_since(record)
    expected = [stale] if stale is not None else [True, False]
    assert shown in [render_one(name, table, s) for s in expected], (
        "the docs differ from benchmarks/results: run python benchmarks/render_readme.py"
    )
    assert f"Measured at `{record['commit'][:10]}`" in shown


def test_caption_says_what_a_reader_must_know():
    record = {
        "commit": "0123456789abcdef" * 2 + "01234567",
        "date": "2026-11-26",
        "command": "python benchmarks/fk.py",
        "clean": False,
        "machine": "a CPU",
        "versions": "jax 0",
    }
    text = caption(record, stale=True)
    assert "Measured at `0123456789`" in text and "uncommitted changes" in text
    assert "changed since" in text
    assert "uncommitted" not in caption(record | {"clean": True}, stale=False)
    assert "changed since" not in caption(record, stale=False)
    table = {"columns": ["a", "b"], "align": "lr", "rows": [["x", "1"]]}
    assert markdown(table) == "| a | b |\n| --- | ---: |\n| x | 1 |"
    piped = {"columns": ["|x|"], "align": "l", "rows": [["a | b"]]}
    assert markdown(piped) == "| \\|x\\| |\n| --- |\n| a \\| b |"
    assert json.loads(json.dumps(table)) == table


def test_goals_table_shows_each_figure_beside_its_goal_met_or_not():
    goals = [
        {"figure": "a", "measured": "1 s", "success": "", "goal": "< 2 s", "met": True},
        {"figure": "b", "measured": "3 s", "success": "99.0%", "goal": "< 2 s", "met": False},
        {"figure": "c", "measured": "(--quick)", "success": "", "goal": "< 2 s", "met": None},
    ]
    table = goals_table(goals)
    assert table["columns"][3:] == ["goal", "met / not met"]
    assert [r[3:] for r in table["rows"]] == [
        ["< 2 s", "met"],
        ["< 2 s", "**not met**"],
        ["< 2 s", "not measured"],
    ]


def test_compile_from_cold_is_the_first_call_minus_the_second():
    limit = f"< {GOAL_COLD_COMPILE_S:.2f} s"
    fast = cold_compile_goal("f", {"first_s": 4.5, "second_s": 0.5})
    assert (fast.measured, fast.goal, fast.met) == ("4.00 s", limit, True)
    slow = cold_compile_goal("f", {"first_s": 5.5, "second_s": 0.25})
    assert (slow.measured, slow.met) == ("5.25 s", False)
    unsolved = cold_compile_goal("f", {"first_s": 1.0, "second_s": 0.5}, success=0.5)
    assert unsolved.met is False and unsolved.success == "50.0%"
    assert cold_compile_goal("f", None).met is False  # the fresh process failed
    skipped = cold_compile_goal("f", None, "--quick")
    assert skipped.met is None and skipped.measured == "(--quick)"


def test_fresh_process_runs_with_an_empty_compilation_cache():
    """What a compile-from-cold figure stands on: a new interpreter with benchmarks/ on its
    path, JAX as asked and a compilation cache of its own, empty (regression: with JAX's
    cache switched off, diffbody still read the programs an earlier run had exported into
    the user's cache), removed afterwards; a failure is None."""
    code = (
        "import os, jax\n"
        "import diffbody\n"
        "from common import print_first_and_second\n"
        "folder = jax.config.jax_compilation_cache_dir\n"
        "print_first_and_second(lambda: jax.numpy.zeros(2), x64=jax.config.jax_enable_x64,\n"
        "    folder=folder, empty=not os.listdir(folder))"
    )
    line = fresh_process(code, "cpu", x64=True)
    assert line is not None and line["first_s"] >= 0 and line["second_s"] >= 0
    assert line["x64"] is True and line["empty"] and "diffbody-cold-" in line["folder"]
    assert not os.path.exists(line["folder"])
    assert fresh_process("raise SystemExit(3)", "cpu") is None
