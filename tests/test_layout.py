"""The package's layout (docs/design.md, "Families and how data flows"), read from the source
with `ast`, imports inside functions included, so that what these rules forbid cannot come
back:

- no import cycle between modules, the command line included (importing a module also runs
  the `__init__` of every package above it that its importer is not already inside);
- no name starting with an underscore imported from another module: what two modules share
  is a public, documented name of the module that owns it;
- the core (the top-level modules) imports no sub-package, and a sub-package imports only
  from the core and the sub-packages before it in `ORDER`;
- no module longer than `MAX_LINES`;
- no module outside `files/` reads a file's contents, but the long runs' own stores (`runs/`)
  and the core's caches (`READERS_ELSEWHERE`).

Each rule is a function of a {module name: path} map, run on diffbody and on a small broken
package, so that each is seen to fail.
"""

import ast
import json
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "diffbody"
# A sub-package may import from the core and from those before it, never from those after.
ORDER = (
    "files",
    "runs",
    "anthropometry",
    "contact",
    "problem",
    "ik",
    "mocap",
    "clouds",
    "images",
    "export",
    "viewer",
    "cli",
)
MAX_LINES = 450
# Reading a file: these calls (an attribute's name, or a module's function), and `open` in a
# mode that reads (no mode, or one with "r" or "+").
READING_METHODS = {"read_text", "read_bytes", "load", "loads", "loadtxt", "genfromtxt", "parse"}
READING_FUNCTIONS = {("json", "load"), ("np", "load"), ("np", "loadtxt"), ("np", "genfromtxt")}
READING_FUNCTIONS |= {("ET", "parse"), ("csv", "reader"), ("csv", "DictReader"), ("pickle", "load")}
READING_FUNCTIONS |= {("zipfile", "ZipFile")}
READERS_ELSEWHERE = {
    "diffbody._programs": "the exported programs beside JAX's compilation cache",
    "diffbody._memory_maps": "/proc's count of the process's memory maps",
}


def modules_of(package: Path) -> dict[str, Path]:
    """{dotted module name: file} for every module of the package."""
    out = {}
    for path in sorted(package.rglob("*.py")):
        parts = path.relative_to(package.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imports_of(modules: dict[str, Path], module: str) -> list[tuple[str, str]]:
    """(source module, imported name or "") for each import of the package in `module`."""
    top = module.split(".")[0]
    package = module if modules[module].name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(modules[module].read_text())):
        if isinstance(node, ast.Import):
            found += [(a.name, "") for a in node.names if a.name.split(".")[0] == top]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            if source.split(".")[0] != top:
                continue
            for alias in node.names:
                if f"{source}.{alias.name}" in modules:  # `from . import _module`
                    found.append((f"{source}.{alias.name}", ""))
                else:
                    found.append((source, alias.name))
    return found


def _ancestors(module: str) -> list[str]:
    parts = module.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def _runs(modules: dict[str, Path], module: str) -> set[str]:
    """The modules whose code runs when `module`'s imports run."""
    inside = {*_ancestors(module), module}
    out = set()
    for source, _ in imports_of(modules, module):
        out |= {m for m in (*_ancestors(source), source) if m in modules and m not in inside}
    return out


def cycles(modules: dict[str, Path]) -> list[str]:
    """One import cycle per strongly connected part found by a depth-first walk."""
    graph = {m: sorted(_runs(modules, m)) for m in modules}
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    found = []

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for n in graph[m]:
            if state.get(n) == 1:
                found.append(" -> ".join(path[path.index(n) :] + [n]))
            elif n not in state:
                visit(n, path + [n])
        state[m] = 2

    for m in modules:
        if m not in state:
            visit(m, [m])
    return found


def private_crossings(modules: dict[str, Path]) -> list[str]:
    return [
        f"{module} imports {name} from {source}"
        for module in modules
        for source, name in imports_of(modules, module)
        if name.startswith("_") and not name.startswith("__") and source != module
    ]


def family(module: str) -> str:
    """'core' for the top level (the package's own modules), else the sub-package's name;
    `python -m diffbody` (`__main__`) runs the command line, so it is the cli's."""
    parts = module.split(".")
    if parts[1:] == ["__main__"]:
        return "cli"
    return (
        parts[1] if len(parts) > 2 or (len(parts) == 2 and not parts[1].startswith("_")) else "core"
    )


def upward_imports(modules: dict[str, Path], order=ORDER) -> list[str]:
    rank = {"core": -1, **{name: i for i, name in enumerate(order)}}
    top = next(iter(modules)).split(".")[0]
    return [
        f"{module} ({family(module)}) imports {source} ({family(source)})"
        for module in modules
        if module != top  # the package's __init__ gathers the public API of every family
        for source, _ in imports_of(modules, module)
        if source in modules and rank[family(source)] > rank[family(module)]
    ]


def long_modules(modules: dict[str, Path]) -> dict[str, int]:
    lengths = {m: len(p.read_text().splitlines()) for m, p in modules.items()}
    return {m: n for m, n in lengths.items() if n > MAX_LINES}


DIFFBODY = modules_of(PACKAGE)


def _reads(call: ast.Call) -> bool:
    f = call.func
    if isinstance(f, ast.Name) and f.id == "open":
        mode = call.args[1] if len(call.args) > 1 else None
        mode = next((k.value for k in call.keywords if k.arg == "mode"), mode)
        if mode is None:
            return True
        return not isinstance(mode, ast.Constant) or bool(set(mode.value) & set("r+"))
    if isinstance(f, ast.Attribute):
        if isinstance(f.value, ast.Name) and (f.value.id, f.attr) in READING_FUNCTIONS:
            return True
        return f.attr in ("read_text", "read_bytes")
    return False


def file_readers(modules: dict[str, Path], allowed=("files", "runs")) -> list[str]:
    """`module:line` of every call that reads a file outside the families `allowed` and
    `READERS_ELSEWHERE`."""
    return [
        f"{module}:{node.lineno}"
        for module, path in modules.items()
        if family(module) not in allowed and module not in READERS_ELSEWHERE
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.Call) and _reads(node)
    ]


def test_every_module_belongs_to_a_family():
    assert {family(m) for m in DIFFBODY} == {"core", *ORDER}
    assert family("diffbody._chain") == "core" and family("diffbody.ik._reach") == "ik"
    assert family("diffbody.cli") == "cli"


def test_no_import_cycle():
    assert not cycles(DIFFBODY)


def test_no_private_name_crosses_a_module():
    assert not private_crossings(DIFFBODY)


def test_families_import_only_the_core_and_the_families_before_them():
    assert not upward_imports(DIFFBODY)


def test_no_module_is_too_long():
    assert not long_modules(DIFFBODY)


def test_every_file_reader_is_in_files():
    assert not file_readers(DIFFBODY)


def test_each_rule_finds_what_it_forbids(tmp_path):
    """A small package with one of each fault: a cycle through an import inside a function,
    a private name taken from another module, the core importing a sub-package, a long
    module, a file read outside `files`."""
    pkg = tmp_path / "pkg"
    (pkg / "cli").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from ._core import walk\n")
    (pkg / "_core.py").write_text(
        "def walk():\n    from .cli._main import main\n\n" + "\n" * MAX_LINES
    )
    (pkg / "cli" / "__init__.py").write_text("from ._main import main\n")
    (pkg / "cli" / "_main.py").write_text(
        "from .._core import walk, _step\n\ndef main(path):\n    return open(path).read()\n"
    )
    (pkg / "files").mkdir()
    (pkg / "files" / "__init__.py").write_text("def read(p):\n    return open(p, 'rb').read()\n")
    modules = modules_of(pkg)
    assert cycles(modules) == ["pkg._core -> pkg.cli -> pkg.cli._main -> pkg._core"]
    assert private_crossings(modules) == ["pkg.cli._main imports _step from pkg._core"]
    assert upward_imports(modules) == ["pkg._core (core) imports pkg.cli._main (cli)"]
    assert long_modules(modules) == {"pkg._core": MAX_LINES + 3}
    assert file_readers(modules) == ["pkg.cli._main:4"]


def names_taken_from(sources: dict[str, str], package) -> list[str]:
    """`db.NAME` in each source (tests, benchmarks, notebooks) that `package` lacks."""
    missing = []
    for where, text in sources.items():
        for node in ast.walk(ast.parse(text)):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id == "db"
                and not hasattr(package, node.attr)
            ):
                missing.append(f"{where}:{node.lineno} db.{node.attr}")
    return missing


def _user_sources() -> dict[str, str]:
    root = PACKAGE.parent
    out = {
        str(p.relative_to(root)): p.read_text()
        for folder in ("tests", "benchmarks", "data")
        for p in sorted((root / folder).rglob("*.py"))
    }
    for path in sorted((root / "notebooks").glob("*.ipynb")):
        cells = json.loads(path.read_text())["cells"]
        code = ["".join(c["source"]) for c in cells if c["cell_type"] == "code"]
        # IPython magics and shell lines are not Python.
        lines = [
            ln for ln in "\n".join(code).splitlines() if not ln.lstrip().startswith(("%", "!"))
        ]
        out[str(path.relative_to(root))] = "\n".join(lines)
    return out


def test_tests_benchmarks_and_notebooks_use_names_diffbody_has():
    """A name moved or made private in the package is caught here, not after a long run
    (`db._anthropometry` outlived the move into sub-packages)."""
    import diffbody

    assert not names_taken_from(_user_sources(), diffbody)
    broken = {"t.py": "import diffbody as db\ndb.forward\ndb._anthropometry._default_prior\n"}
    assert names_taken_from(broken, diffbody) == ["t.py:3 db._anthropometry"]
