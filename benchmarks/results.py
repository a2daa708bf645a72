"""Results files: what a benchmark run measured, written where the README's tables are
rendered from (`benchmarks/render_readme.py`).

A run writes `benchmarks/results/NAME.json`:

    {"benchmark": "fk", "command": "python benchmarks/fk.py", "commit": "<sha>",
     "clean": true, "date": "2026-11-26", "machine": "...", "versions": "...",
     "conditions": {...}, "tables": {"ID": {"columns": [...], "align": "rl", "rows": [...]}},
     "goals": [{"figure": ..., "measured": ..., "success": ..., "goal": ..., "met": ...}]}

`clean` is whether `diffbody/` and `benchmarks/` had no uncommitted change when the run
started: only then does `commit` name the code that was measured. Cells are strings, formatted
by the benchmark, so that the README shows exactly what the run printed. A `--quick` run is a
smoke run: it writes only where `--out` says (CI writes to a temporary folder).
"""

import datetime
import json
import subprocess
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
# What a results file's commit must describe: the package and the benchmarks.
MEASURED_PATHS = ("diffbody", "benchmarks")


def git(*args: str) -> str | None:
    try:
        out = subprocess.run(
            ["git", *args], cwd=ROOT, capture_output=True, text=True, check=True, timeout=30
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip()


def commit_and_clean() -> tuple[str, bool]:
    """(HEAD's sha or "unknown", whether diffbody/ and benchmarks/ match it), results files
    aside (a run rewrites them)."""
    sha = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--", *MEASURED_PATHS)
    if sha is None or status is None:
        return "unknown", False
    changed = [line for line in status.splitlines() if "benchmarks/results/" not in line]
    return sha, not changed


@dataclass
class Table:
    """A table as the README shows it: a header, one alignment letter per column ("l" or "r"),
    rows of already formatted cells."""

    columns: list[str]
    align: str
    rows: list[list[str]] = field(default_factory=list)

    def add(self, *cells) -> None:
        if len(cells) != len(self.columns):
            raise ValueError(f"{len(cells)} cells for columns {self.columns}")
        self.rows.append([str(c) for c in cells])


@dataclass
class Run:
    """One benchmark run's record; start it before measuring (it reads the commit then)."""

    benchmark: str
    command: str
    machine: str
    versions: str
    conditions: dict
    quick: bool = False
    tables: dict[str, Table] = field(default_factory=dict)
    goals: list[dict] = field(default_factory=list)
    commit: str = ""
    clean: bool = False
    date: str = ""

    def __post_init__(self):
        self.commit, self.clean = commit_and_clean()
        self.date = datetime.date.today().isoformat()

    def table(self, name: str, columns: list[str], align: str) -> Table:
        if len(align) != len(columns):
            raise ValueError(f"align {align!r} for {len(columns)} columns")
        self.tables[name] = Table(list(columns), align)
        return self.tables[name]

    def add_goals(self, goals) -> None:
        """`common.Goal`s: each figure beside its goal."""
        self.goals += [asdict(g) for g in goals]

    def write(self, out: Path | None) -> Path | None:
        """Write `out / NAME.json` (`out` None: nowhere, for a quick run without --out)."""
        if out is None:
            return None
        out.mkdir(parents=True, exist_ok=True)
        path = out / f"{self.benchmark}.json"
        record = asdict(self)
        path.write_text(json.dumps(record, indent=1) + "\n")
        print(f"results written to {path}")
        return path


def out_dir(out: str | None, quick: bool) -> Path | None:
    """Where a run writes: --out if given, else benchmarks/results for a full run and nowhere
    for a quick one (a smoke run must not replace measured figures)."""
    if out is not None:
        return Path(out)
    return None if quick else RESULTS


def add_arguments(parser) -> None:
    """--quick and --out, the same in every benchmark."""
    parser.add_argument(
        "--quick", action="store_true", help="small sizes, no peers: a smoke run (as in CI)"
    )
    parser.add_argument(
        "--out",
        default=None,
        help="folder for NAME.json (default: benchmarks/results, or nowhere with --quick)",
    )


def load(path: Path) -> dict:
    return json.loads(Path(path).read_text())
