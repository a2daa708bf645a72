"""Start-up: what a new user waits for, every figure measured in a fresh Python process.

    python benchmarks/startup.py [--repeats N] [--quick] [--out DIR]

Each figure is a new interpreter (a subprocess) on the CPU, float32, with the defaults a user
gets: none of this process's JAX_*, XLA_* or DIFFBODY_* variables (the test suite's XLA flags
and cache settings) reach it. It runs twice over one compilation cache: cold (a new, empty
temporary folder as JAX_COMPILATION_CACHE_DIR), then cached (the same folder again). It runs
with JAX_LOG_COMPILES=1: the lines "Finished XLA compilation of jit(NAME) in S sec" of its
stderr give the programs and XLA's seconds (a persistent-cache hit logs such a line too, its
seconds the read-back; "compiles" counts the others), the "Finished tracing" and "Finished
jaxpr to MLIR module conversion" lines the seconds spent tracing and lowering.

1. The README's command, `diffbody reach --effector left_hand.palm --target 0.35 0.3 1.1 --out
   reach.pose.json --png reach.png`, in a temporary folder: the wall time of the process; and
   once more cold with the solve programs compiled with XLA's defaults
   (DIFFBODY_XLA_DEFAULTS=1), which shows what diffbody's compile options save; and once
   with a new cache that holds only the cached run's exported programs (`diffbody-exported`),
   which shows what shipping them with the package would save: XLA compiles as cold, nothing
   is traced or lowered.
2. `solve_reach` on the whole body, standing (the default), `db.load_body()`, one palm target
   0.9 m in front of the left shoulder's rest position and 10 cm below it (docs/guide.md, the
   reach ladder: the hips and the spine join the arm): the first call (import and
   `load_body` apart, cold and cached) and a warm call (the median of 20 more calls on the same
   target). Importing diffbody turns the cache on (`diffbody._programs.keep_compiled`): every
   program is kept, and the solve programs are exported beside it.
   Then, in the same process, three arm reaches with other effectors (another wrist, two
   targets, a palm and its direction), another far reach (the left wrist: the trunk joins,
   standing) and one with a segment subset (the left arm: no standing): the programs each
   compiles (goal 0 for the three: the limbs' phase runs on a limb chain's program, one
   limb, or the whole tree's, several limbs, the problem as data, docs/design.md section 6;
   the standing phase keeps a program per layout).
3. `import diffbody` (of which `import jax`), after an untimed `compileall` of the package.

`--repeats N` fresh processes per figure (default 3; --quick 1): the median and the range.
`--quick`: 3 warm calls instead of 20, still every figure. Goals: a first answer in seconds
(README command < 4 s cold and < 1.5 s cached; the standing whole-body solve's first call
< 5 s cold and < 1.5 s cached, a warm call < 2 ms).
"""

import argparse
import compileall
import importlib.util
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import results
from common import goal, machine, print_goals, select_device, start_run
from ik import CLI_TARGET, EFFECTOR
from render_readme import markdown

GOAL_CLI_COLD_S, GOAL_CLI_CACHED_S = 4.0, 1.5  # the README command, wall
GOAL_FIRST_CALL_COLD_S, GOAL_FIRST_CALL_CACHED_S = 5.0, 1.5  # whole body, standing
GOAL_WARM_MS = 2.0
DEFAULTS_ROW = "diffbody reach, README command, XLA's defaults (DIFFBODY_XLA_DEFAULTS=1) (s)"
EXPORTED_ROW = "diffbody reach, README command, the exported programs alone kept (s)"

# m: the left shoulder at rest, (0, 0.193, 1.388), + (0.9, 0, -0.1): the guide's reach ladder
REACH_TARGET = (0.9, 0.193, 1.288)
TOP = 8  # programs shown by XLA seconds
LOG = re.compile(
    r"Finished (XLA compilation of|tracing|jaxpr to MLIR module conversion) (\S+)"
    r"(?: for jit)? in ([0-9.]+) sec"
)
CHILD = """\
import json, statistics, sys, time
import diffbody as db
import jax

def solve():
    t0 = time.perf_counter()
    out = jax.block_until_ready(db.solve_reach(body, [db.Target.position({effector!r}, {xyz!r})]))
    return out, time.perf_counter() - t0

print("@@ load_body", file=sys.stderr, flush=True)
t0 = time.perf_counter()
body = db.load_body()
load_s = time.perf_counter() - t0
print("@@ first", file=sys.stderr, flush=True)
out, first_s = solve()
print("@@ check", file=sys.stderr, flush=True)
line = dict(load_s=load_s, first_s=first_s, status=db.ReachStatus(int(out.status)).name,
    residual_mm=1e3 * float(out.residuals.max()), trunk=out.pose.spine_target is not None)
print("@@ warm", file=sys.stderr, flush=True)
line["warm_s"] = statistics.median(solve()[1] for _ in range({warm}))
print("@@ others", file=sys.stderr, flush=True)
palm_down = db.Target.axis_direction("right_hand", (0, 1, 0), (0, 0, -1))
others = [
    [db.Target.position("right_wrist", (-0.25, 0.3, 1.15))],
    [db.Target.position("left_wrist", (0.3, 0.4, 1.2)),
     db.Target.position("right_hand.palm", (-0.3, 0.3, 1.1))],
    [db.Target.position("right_hand.palm", (-0.3, 0.35, 1.2)), palm_down],
]
line["others"] = [db.ReachStatus(int(db.solve_reach(body, t).status)).name for t in others]
print("@@ far", file=sys.stderr, flush=True)
out = db.solve_reach(body, [db.Target.position("left_wrist", (0.3, 0.8, 0.8))])
line["others"].append(db.ReachStatus(int(out.status)).name)
print("@@ subset", file=sys.stderr, flush=True)
arm = ["left_clavicle", "left_upper_arm", "left_forearm", "left_hand"]
out = db.solve_reach(body, [db.Target.position("left_wrist", (0.3, 0.3, 1.2))], segments=arm)
line["others"].append(db.ReachStatus(int(out.status)).name)
print(json.dumps(line))
"""
OTHERS_ROW = "then 3 other arm reaches (effectors, 2 targets, a palm direction): programs compiled"
FAR_ROW = "then another far reach, standing (another effector): programs compiled"
SUBSET_ROW = "then a segment subset (no standing: no constraint): programs compiled"
IMPORT = """\
import json, time
t0 = time.perf_counter()
import jax
t1 = time.perf_counter()
import diffbody
print(json.dumps(dict(import_s=time.perf_counter() - t0, jax_s=t1 - t0)))
"""


@dataclass
class Compiles:
    """What one phase of a process compiled, from its JAX_LOG_COMPILES lines."""

    programs: list[tuple[str, float]] = field(default_factory=list)  # (name, XLA seconds)
    hits: int = 0  # of those, read back from the persistent cache
    trace_lower_s: float = 0.0

    @property
    def count(self) -> int:
        return len(self.programs) - self.hits

    @property
    def xla_s(self) -> float:
        return sum(s for _, s in self.programs)


def parse_log(stderr: str) -> dict[str, Compiles]:
    """Each phase's Compiles; a line "@@ NAME" (the child's) starts phase NAME."""
    phases, phase = defaultdict(Compiles), "start"
    for line in stderr.splitlines():
        if line.startswith("@@ "):
            phase = line[3:].strip()
        elif "Persistent compilation cache hit" in line:
            phases[phase].hits += 1
        elif m := LOG.search(line):
            if m[1] == "XLA compilation of":
                phases[phase].programs.append((m[2], float(m[3])))
            else:
                phases[phase].trace_lower_s += float(m[3])
    return phases


def fresh(
    argv: list[str], cache: str, cwd: str, **extra: str
) -> tuple[float, str, dict[str, Compiles]]:
    """Run argv as a user would, the compilation cache in `cache` (and `extra` variables):
    (wall seconds, its stdout, its phases' compiles). A failure stops the benchmark with its
    output."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_", "XLA_", "DIFFBODY_"))}
    env.update(JAX_PLATFORMS="cpu", JAX_COMPILATION_CACHE_DIR=cache, JAX_LOG_COMPILES="1")
    env.update(extra)
    t0 = time.perf_counter()
    proc = subprocess.run(argv, env=env, cwd=cwd, capture_output=True, text=True)
    wall_s = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(
            f"{' '.join(argv)[:200]} failed:\n{proc.stdout[-3000:]}{proc.stderr[-3000:]}"
        )
    return wall_s, proc.stdout, parse_log(proc.stderr)


def reach_command() -> list[str]:
    """The README's command, run where it should write."""
    script = Path(sys.executable).with_name("diffbody")
    command = [str(script)] if script.exists() else [sys.executable, "-m", "diffbody"]
    command += ["reach", "--effector", EFFECTOR, "--target", *map(str, CLI_TARGET)]
    return command + ["--out", "reach.pose.json", "--png", "reach.png"]


def spread(values: list[float], fmt: str = ".2f") -> str:
    """The median, and the range when there is more than one value."""
    med = f"{statistics.median(values):{fmt}}"
    return med if len(values) == 1 else f"{med} ({min(values):{fmt}}-{max(values):{fmt}})"


def top_programs(phase: Compiles) -> list[tuple[str, int, float]]:
    """(name, times compiled, XLA seconds) of the programs taking the most XLA seconds."""
    by_name = defaultdict(lambda: [0, 0.0])
    for name, s in phase.programs:
        by_name[name][0] += 1
        by_name[name][1] += s
    return sorted(((n, c, s) for n, (c, s) in by_name.items()), key=lambda r: -r[2])[:TOP]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    results.add_arguments(parser)
    parser.add_argument("--repeats", type=int, default=None, help="fresh processes (3; quick 1)")
    args = parser.parse_args()
    select_device("cpu")
    sys.stdout.reconfigure(line_buffering=True)
    repeats = args.repeats or (1 if args.quick else 3)
    warm = 3 if args.quick else 20
    package = Path(importlib.util.find_spec("diffbody").origin).parent
    compileall.compile_dir(package, quiet=1)  # Python's bytecode cache, as an install writes it
    print(machine())
    print(f"diffbody from {package}; {repeats} fresh process(es) per figure: median (range)")
    run_record = start_run(
        "startup", args, repeats=repeats, warm_calls=warm, reach_target=REACH_TARGET
    )

    rows = defaultdict(lambda: defaultdict(list))  # figure -> column -> values
    first_cold: dict[str, Compiles] = {}  # repetition 1's, for the top programs

    def add(figure: str, state: str, value: float, phase: Compiles | None = None) -> None:
        rows[figure][state].append(value)
        for key, x in (("compiles", "count"), ("xla", "xla_s"), ("trace", "trace_lower_s")):
            if phase is not None:
                rows[figure][f"{key} {state}"].append(getattr(phase, x))

    child = CHILD.format(effector=EFFECTOR, xyz=REACH_TARGET, warm=warm)
    warm_row = f"solve_reach: warm, median of {warm} (ms)"
    for rep in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            _, stdout, phases = fresh([sys.executable, "-c", IMPORT], tmp, tmp)
        line = json.loads(stdout.splitlines()[-1])
        add("import diffbody (s)", "cold", line["import_s"], phases["start"])
        add("  of which import jax (s)", "cold", line["jax_s"])
        with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out_dir:
            for state in ("cold", "cached"):
                wall_s, _, phases = fresh(reach_command(), cache, out_dir)
                add("diffbody reach, README command (s)", state, wall_s, phases["start"])
                if rep == 0 and state == "cold":
                    first_cold["diffbody reach"] = phases["start"]
            # What shipping the exported programs would give: a new cache holding them alone.
            with tempfile.TemporaryDirectory() as shipped:
                exported = "diffbody-exported"
                shutil.copytree(Path(cache) / exported, Path(shipped) / exported)
                wall_s, _, phases = fresh(reach_command(), shipped, out_dir)
                add(EXPORTED_ROW, "cold", wall_s, phases["start"])
        # The same, its programs compiled with XLA's defaults (diffbody._programs.CPU_OPTIONS
        # off): what the per-program options save.
        with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out_dir:
            wall_s, _, phases = fresh(reach_command(), cache, out_dir, DIFFBODY_XLA_DEFAULTS="1")
            add(DEFAULTS_ROW, "cold", wall_s, phases["start"])
        with tempfile.TemporaryDirectory() as cache:
            for state in ("cold", "cached"):
                _, stdout, phases = fresh([sys.executable, "-c", child], cache, cache)
                line = json.loads(stdout.splitlines()[-1])
                add("solve_reach: load_body (s)", state, line["load_s"], phases["load_body"])
                add("solve_reach: first call (s)", state, line["first_s"], phases["first"])
                add(warm_row, state, line["warm_s"] * 1e3, phases["warm"])
                add(OTHERS_ROW, state, phases["others"].count, phases["others"])
                add(FAR_ROW, state, phases["far"].count, phases["far"])
                add(SUBSET_ROW, state, phases["subset"].count, phases["subset"])
                if rep == 0 and state == "cold":
                    first_cold["solve_reach first call"] = phases["first"]
                    print(
                        f"solve_reach to {REACH_TARGET}: {line['status']}, residual "
                        f"{line['residual_mm']:.3f} mm, trunk joined: {line['trunk']}; "
                        f"the other solves: {', '.join(line['others'])}"
                    )
        print(f"repetition {rep + 1} of {repeats} done")

    columns = ["figure", "cold", "cached"]
    columns += [f"{what} (cold / cached)" for what in ("compiles", "XLA s", "trace+lower s")]
    table = run_record.table("startup", columns, "lrrrrr")
    for figure, row in rows.items():
        cells = [spread(row["cold"]), spread(row["cached"]) if row["cached"] else "-"]
        for key, fmt in (("compiles", ".0f"), ("xla", ".2f"), ("trace", ".2f")):
            pair = (row[f"{key} cold"], row[f"{key} cached"])
            cells.append(" / ".join(spread(v, fmt) for v in pair if v) or "-")
        table.add(figure, *cells)
    print(f"\n{markdown(vars(table))}")

    programs = run_record.table("programs", ["where", "program", "compiles", "XLA s"], "llrr")
    for where, phase in first_cold.items():
        print(f"\n{where}, cold (repetition 1): {phase.count} compiles, {phase.xla_s:.2f} XLA s")
        for name, count, s in top_programs(phase):
            print(f"  {name:<40} {count:>4}  {s:6.2f} s")
            programs.add(where, name, count, f"{s:.2f}")

    med = {f: {k: statistics.median(v) for k, v in r.items() if v} for f, r in rows.items()}
    cli, first = med["diffbody reach, README command (s)"], med["solve_reach: first call (s)"]
    warm_ms = med[warm_row]["cold"]
    goals = [
        goal(name, value, limit, fmt=".2f", unit=unit, op="<")
        for name, value, limit, unit in (
            ("README reach command, empty cache, wall", cli["cold"], GOAL_CLI_COLD_S, " s"),
            ("README reach command, filled cache, wall", cli["cached"], GOAL_CLI_CACHED_S, " s"),
            (
                "solve_reach standing, first call, empty cache",
                first["cold"],
                GOAL_FIRST_CALL_COLD_S,
                " s",
            ),
            (
                "solve_reach standing, first call, filled cache",
                first["cached"],
                GOAL_FIRST_CALL_CACHED_S,
                " s",
            ),
            (f"solve_reach standing, warm, median of {warm}", warm_ms, GOAL_WARM_MS, " ms"),
        )
    ]
    for state in ("cold", "cached"):
        figure = f"3 other arm reaches after the first, {state}: programs compiled"
        goals.append(goal(figure, med[OTHERS_ROW][state], 0, fmt=".0f", op="<="))
    print_goals(goals, f"goals (medians of {repeats} fresh processes; 2-core CPU goals, float32)")
    run_record.add_goals(goals)
    run_record.write(results.out_dir(args.out, args.quick))


if __name__ == "__main__":
    main()
