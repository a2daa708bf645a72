"""Render the documentation's benchmark tables from the committed results files.

    python benchmarks/render_readme.py           # rewrite the pages between the markers
    python benchmarks/render_readme.py --check   # exit 1 if a page differs

The pages are `PAGES`: docs/benchmarks.md, and docs/guide.md where a workflow quotes its
own figures.

A table sits between `<!-- results NAME TABLE -->` and `<!-- /results -->`: NAME is the
results file `benchmarks/results/NAME.json`, TABLE one of its tables, or `goals` for its
goals table. Above each table a caption says which command measured it, at which commit, on
which machine, and whether the code has changed since (then the figures describe older code
until the benchmark runs again).
"""

import argparse
import re
import sys

from results import RESULTS, ROOT, git, load

PAGES = (ROOT / "docs" / "benchmarks.md", ROOT / "docs" / "guide.md")
MARKER = re.compile(
    r"(<!-- results (?P<name>[\w-]+) (?P<table>[\w-]+) -->\n)(?P<body>.*?)(<!-- /results -->)",
    re.S,
)


def changed_since(record: dict) -> bool | None:
    """Whether diffbody/ or the benchmark's script changed after the run's commit (None: git
    cannot tell, e.g. a shallow clone without that commit)."""
    script = record["command"].split()[1]
    if git("cat-file", "-e", f"{record['commit']}^{{commit}}") is None:
        return None
    diff = git("diff", "--name-only", record["commit"], "HEAD", "--", "diffbody", script)
    return None if diff is None else bool(diff)


def caption(record: dict, stale: bool | None) -> str:
    text = (
        f"Measured at `{record['commit'][:10]}` on {record['date']} by "
        f"`{record['command']}`"
        + ("" if record["clean"] else ", with uncommitted changes to the code")
        + f". {record['machine']}; {record['versions']}."
    )
    if stale:
        text += " The code has changed since: these figures describe that commit."
    return text


def goals_table(goals: list[dict]) -> dict:
    rows = [
        [
            g["figure"],
            g["measured"],
            g["success"],
            g["goal"],
            "not measured" if g["met"] is None else ("met" if g["met"] else "**not met**"),
        ]
        for g in goals
    ]
    return {
        "columns": ["figure", "measured", "success", "goal", "met / not met"],
        "align": "lrrrl",
        "rows": rows,
    }


def markdown(table: dict) -> str:
    sep = {"l": "---", "r": "---:"}

    def row(cells) -> str:  # a "|" inside a cell would end it
        return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"

    lines = [row(table["columns"]), "| " + " | ".join(sep[a] for a in table["align"]) + " |"]
    return "\n".join(lines + [row(r) for r in table["rows"]])


def render_one(name: str, table: str, stale: bool | None = "git") -> str:
    """The text between one pair of markers. `stale`: "git" asks git; True/False/None force
    the caption's last sentence (the README test renders both where git cannot tell)."""
    path = RESULTS / f"{name}.json"
    if not path.exists():
        raise SystemExit(f"no results file {path.relative_to(ROOT)} for {name}")
    record = load(path)
    if stale == "git":
        stale = changed_since(record)
    if table == "goals":
        body = goals_table(record["goals"])
    elif table in record["tables"]:
        body = record["tables"][table]
    else:
        raise SystemExit(
            f"{path.relative_to(ROOT)}: no table {table!r} (has {sorted(record['tables'])})"
        )
    return f"\n{caption(record, stale)}\n\n{markdown(body)}\n\n"


def render(text: str) -> str:
    return MARKER.sub(lambda m: m.group(1) + render_one(m["name"], m["table"]) + m.group(5), text)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a page differs")
    args = parser.parse_args()
    for page in PAGES:
        text = page.read_text()
        new = render(text)
        if args.check:
            if new != text:
                sys.exit(
                    f"{page.name}'s tables differ from benchmarks/results: run render_readme.py"
                )
            continue
        page.write_text(new)
        print(f"{len(MARKER.findall(text))} tables rendered into {page.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
