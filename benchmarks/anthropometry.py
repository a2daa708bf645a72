"""Anthropometry: held-out scaling accuracy on ANSUR II and whole populations; every figure
beside its goal, with the machine and versions.

    python benchmarks/anthropometry.py [--x64] [--quick] [--out DIR]

1. **Held-out accuracy.** Per sex, the population prior is fitted on the even rows of the
   ANSUR II file (0-based: rows 0, 2, 4, ...). Each odd row is scaled (`scale_population`,
   the same as `scale_to` one at a time) from stature and weight only, and again from five
   inputs (stature, weight, span, sitting height, hip breadth); the scaled body is then
   measured. Figure: the mean absolute error over the 19 (resp. 16) other length
   measurements against the subject's real values, mean over those measurements. Measured in
   the same run on the same split: uniform scaling of the even rows' mean body by stature,
   and the best linear predictor (least squares on the even rows) from the inputs, the floor
   of any method that sees only the inputs. Goals: <= 12.5 mm from stature and weight,
   <= 9 mm from the five inputs.
2. **Population.** All ANSUR II subjects (both sexes, each with its own prior of every row)
   scaled from stature and weight, and from the five inputs: the compile time (the first
   call minus the second) and the run time of the whole population (the second call),
   printed apart, < 10 s each, every given measurement reproduced within 1 mm.

Sphere-cloud fits have their own benchmark: benchmarks/_sphere_cloud.py. `--quick` scales
every 20th held-out row of one sex and the population from stature and weight only.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import results  # noqa: E402
from common import goal, machine, print_goals, select_device, start_run, versions  # noqa: E402

FIVE = ("stature", "weightkg", "span", "sittingheight", "hipbreadth")
SEXES = ("male", "female")


def held_out(db, sex: str, known: tuple[str, ...], every: int = 1) -> dict[str, float]:
    """Mean absolute errors (mm) over the other lengths of the odd rows: diffbody, uniform
    scaling by stature, the linear predictor."""
    from diffbody.anthropometry._prior import ansur2_subjects

    rows, values = ansur2_subjects(sex)
    names = db.MEASUREMENT_NAMES
    train, test = values[rows % 2 == 0], values[rows % 2 == 1][::every]
    prior = db.PopulationPrior.fit(train, sex=sex)
    cols = [names.index(k) for k in known]
    others = [i for i, n in enumerate(names) if n not in known and n != "weightkg"]
    out = db.scale_population(known, test[:, cols], prior=prior, progress=False)
    mae = lambda pred: float(np.mean(np.abs(pred[:, others] - test[:, others])) * 1000)  # noqa: E731
    stature = names.index("stature")
    uniform = train.mean(0) * (test[:, stature] / train[:, stature].mean())[:, None]
    design = lambda v: np.column_stack([np.ones(len(v)), v[:, cols]])  # noqa: E731
    coef, *_ = np.linalg.lstsq(design(train), train, rcond=None)
    return {
        "diffbody": mae(out.measurements),
        "uniform": mae(uniform),
        "linear": mae(design(test) @ coef),
        "reproduced": float(out.reproduced.mean()),
        "errors": np.abs(out.measurements[:, others] - test[:, others]).mean(1) * 1000,
    }


def population(db, known: tuple[str, ...], sexes=SEXES) -> tuple[float, float, float, int]:
    """(compile s, run s, fraction reproduced, subjects) over every subject of `sexes`: the
    run is the second call, the compile time the first call minus the second."""
    from diffbody.anthropometry._prior import ansur2_subjects

    cols = [db.MEASUREMENT_NAMES.index(k) for k in known]
    data = {sex: ansur2_subjects(sex)[1][:, cols] for sex in sexes}
    for sex in sexes:  # the priors of every row, fitted outside the timing
        db.PopulationPrior.ansur2(sex)

    def everyone():
        t0 = time.perf_counter()
        outs = [db.scale_population(known, data[sex], sex=sex, progress=False) for sex in sexes]
        return outs, time.perf_counter() - t0

    _, first = everyone()
    outs, run_s = everyone()
    compile_s = max(first - run_s, 0.0)
    reproduced = np.concatenate([o.reproduced for o in outs]).mean()
    return compile_s, run_s, float(reproduced), sum(len(v) for v in data.values())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--x64", action="store_true", help="float64 (default float32)")
    results.add_arguments(parser)
    args = parser.parse_args()
    select_device("cpu", x64=args.x64)
    import diffbody as db

    print(machine())
    print(versions(["jax", "jaxlib", "optimistix", "equinox", "numpy"]))
    print(f"dtype: {'float64' if args.x64 else 'float32'}")
    goals = []
    inputs = (FIVE[:2],) if args.quick else (FIVE[:2], FIVE)
    sexes = SEXES[:1] if args.quick else SEXES
    every = 20 if args.quick else 1
    run = start_run("anthropometry", args, inputs=inputs, sexes=sexes, held_out_every=every)
    accuracy = run.table(
        "held_out",
        [
            "sex",
            "inputs",
            "diffbody (mm)",
            "uniform scaling (mm)",
            "linear floor (mm)",
            "given reproduced",
            "goal",
        ],
        "lrrrrrl",
    )
    speed = run.table(
        "population",
        ["population, both sexes", "compile (s)", "run (s)", "given reproduced", "goal"],
        "lrrrl",
    )

    # The population first: its first call compiles from cold.
    for known in inputs:
        compile_s, run_s, reproduced, count = population(db, known, sexes)
        tag = f"population, {len(known)} inputs"
        compiled = goal(f"{tag}: compile", compile_s, 10.0, fmt=".1f", unit=" s", op="<")
        ran = goal(
            f"{tag}: run (all {count:,})",
            run_s,
            10.0,
            fmt=".2f",
            unit=" s",
            op="<",
            success=reproduced,
        )
        met = "met" if compiled.met and ran.met else "**not met**"
        speed.add(
            f"{len(known)} inputs, {'all' if sexes == SEXES else sexes[0]} {count:,} subjects",
            f"{compile_s:.1f}",
            f"{run_s:.2f}",
            f"{reproduced:.2%}",
            f"< 10 s each, {met}",
        )
        print(
            f"\npopulation from {len(known)} inputs, {count:,} subjects:\n  compile "
            f"{compile_s:.1f} s (first call - second)\n  run {run_s:.2f} s (second call), "
            f"reproduced {reproduced:.2%}"
        )
        goals += [compiled, ran]

    print("\nheld-out accuracy (prior on even rows, odd rows scaled), MAE in mm")
    print(f"  {'sex':<7}{'inputs':<8}{'diffbody':>9}{'uniform':>9}{'linear':>9}{'reproduced':>12}")
    for known, target in ((FIVE[:2], 12.5), (FIVE, 9.0))[: len(inputs)]:
        for sex in sexes:
            r = held_out(db, sex, known, every)
            print(
                f"  {sex:<7}{len(known):<8}{r['diffbody']:9.2f}{r['uniform']:9.2f}"
                f"{r['linear']:9.2f}{r['reproduced']:12.1%}"
            )
            met = "met" if r["diffbody"] <= target else "**not met**"
            accuracy.add(
                sex,
                len(known),
                f"{r['diffbody']:.2f}",
                f"{r['uniform']:.2f}",
                f"{r['linear']:.2f}",
                f"{r['reproduced']:.1%}",
                f"<= {target:g}, {met}",
            )
            goals.append(
                goal(
                    f"held-out MAE, {sex}, {len(known)} inputs (linear floor {r['linear']:.1f} mm)",
                    r["diffbody"],
                    target,
                    fmt=".2f",
                    unit=" mm",
                    op="<=",
                )
            )
    print_goals(goals, "anthropometry goals", "given measurements reproduced within 1 mm")
    run.add_goals(goals)
    run.write(results.out_dir(args.out, args.quick))


if __name__ == "__main__":
    main()
