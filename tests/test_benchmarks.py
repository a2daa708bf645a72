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

from render_readme import MARKER, README, caption, changed_since, markdown, render_one  # noqa: E402
from results import RESULTS, load  # noqa: E402

# Tables that only a full run fills (peers are not run by --quick).
FULL_RUN_ONLY = {("ik", "peers")}
BENCHMARKS = ("fk", "spine", "ik", "solvers", "anthropometry", "mocap", "webb", "_sphere_cloud")


def readme_tables() -> list[tuple[str, str, str]]:
    """(results name, table, the text between the markers) of each table in README.md."""
    return [(m["name"], m["table"], m["body"]) for m in MARKER.finditer(README.read_text())]


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
        "README.md differs from benchmarks/results: run python benchmarks/render_readme.py"
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
