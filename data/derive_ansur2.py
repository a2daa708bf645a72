"""Derive per-sex percentile tables from the ANSUR II public data files.

Usage::

    python data/derive_ansur2.py [/path/to/ansur2]

The folder must hold ``ANSUR_II_MALE_Public.csv`` and ``ANSUR_II_FEMALE_Public.csv`` (the
public release of the 2012 U.S. Army Anthropometric Survey). The default folder is
``../shared/reference/ansur2`` relative to the repository root. Writes
``data/ansur2_percentiles.csv``: one row per (sex, measurement) for all 93 body measurements,
with columns ``sex,measurement,unit,n,mean,sd,p5,p50,p95``.

Units: millimetres, except ``weightkg`` (stored in the files in 0.1 kg, written here in kg)
and ``interpupillarybreadth`` (stored in 0.1 mm, written here in mm). Statistics are
unweighted sample statistics: ``sd`` is the sample standard deviation (ddof=1) and the
percentiles use numpy's default linear interpolation. The official weighted summary
statistics (Gordon et al. 2014) were not used and may differ slightly.

Not written: the subject id and the demographic columns (Gender, Date, Installation,
Component, Branch, PrimaryMOS, SubjectsBirthLocation, SubjectNumericRace, Ethnicity, DODRace,
Age, and the self-reported Heightin and Weightlbs).

Also writes ``data/ansur2_subjects.csv``: every subject (sex, 0-based row in its file) with
the 21 measurements diffbody models, in the same units, for the population prior
(`diffbody.PopulationPrior`) and the held-out benchmark (benchmarks/anthropometry.py).
"""

from __future__ import annotations

import csv
import pathlib
import sys

import numpy as np

REPO = pathlib.Path(__file__).resolve().parent.parent
DEFAULT_SOURCE = REPO.parent / "shared" / "reference" / "ansur2"
OUTPUT = REPO / "data" / "ansur2_percentiles.csv"
SUBJECTS = REPO / "data" / "ansur2_subjects.csv"
# The measurements diffbody models (diffbody/_measurements.py), written per subject for the
# population prior and the held-out benchmark.
SUBJECT_COLUMNS = (
    "stature",
    "weightkg",
    "span",
    "acromialheight",
    "cervicaleheight",
    "sittingheight",
    "trochanterionheight",
    "kneeheightmidpatella",
    "lateralfemoralepicondyleheight",
    "tibialheight",
    "biacromialbreadth",
    "bideltoidbreadth",
    "hipbreadth",
    "chestdepth",
    "shoulderelbowlength",
    "acromionradialelength",
    "radialestylionlength",
    "handlength",
    "footlength",
    "buttockkneelength",
    "headlength",
)

FILES = (("male", "ANSUR_II_MALE_Public.csv"), ("female", "ANSUR_II_FEMALE_Public.csv"))

# Columns that are not body measurements (compared case-insensitively).
NON_MEASUREMENTS = {
    "subjectid",
    "gender",
    "date",
    "installation",
    "component",
    "branch",
    "primarymos",
    "subjectsbirthlocation",
    "subjectnumericrace",
    "ethnicity",
    "dodrace",
    "age",
    "heightin",
    "weightlbs",
    "writingpreference",
}

# measurement -> (divisor turning the file's unit into the written unit, written unit)
UNITS = {"weightkg": (10.0, "kg"), "interpupillarybreadth": (10.0, "mm")}

HEADER = (
    "# ANSUR II per-sex summary statistics (unweighted sample statistics, numpy linear "
    "percentiles).\n"
    '# Source: Gordon CC, Blackwell CL, Bradtmiller B, et al., 2014, "2012 Anthropometric '
    'Survey of U.S. Army Personnel: Methods and Summary Statistics", NATICK/TR-15/007; '
    "public data release (ANSUR_II_MALE_Public.csv, ANSUR_II_FEMALE_Public.csv).\n"
    "# Derived by data/derive_ansur2.py. Units: mm; weightkg in kg (file: 0.1 kg); "
    "interpupillarybreadth in mm (file: 0.1 mm). sd has ddof=1.\n"
)


def _fmt(x: float) -> str:
    s = f"{x:.3f}".rstrip("0").rstrip(".")
    return "0" if s == "-0" else s


def read_measurements(path: pathlib.Path) -> dict[str, np.ndarray]:
    """Return {measurement name: values in the written unit} for one ANSUR II file."""
    with open(path, encoding="latin-1", newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    out: dict[str, np.ndarray] = {}
    for j, name in enumerate(header):
        if name.strip().lower() in NON_MEASUREMENTS:
            continue
        values = np.array([float(r[j]) for r in body], dtype=float)
        divisor, _ = UNITS.get(name, (1.0, "mm"))
        out[name] = values / divisor
    return out


def main(argv: list[str]) -> None:
    source = pathlib.Path(argv[1]) if len(argv) > 1 else DEFAULT_SOURCE
    lines = [HEADER, "sex,measurement,unit,n,mean,sd,p5,p50,p95\n"]
    for sex, filename in FILES:
        data = read_measurements(source / filename)
        for name, v in data.items():
            unit = UNITS.get(name, (1.0, "mm"))[1]
            p5, p50, p95 = np.percentile(v, [5, 50, 95])
            fields = [sex, name, unit, str(v.size)]
            fields += [_fmt(x) for x in (v.mean(), v.std(ddof=1), p5, p50, p95)]
            lines.append(",".join(fields) + "\n")
    OUTPUT.write_text("".join(lines), encoding="utf-8")
    print(f"wrote {OUTPUT} ({len(lines) - 2} rows)")

    # Every subject, in file order (`row` is the 0-based row of its sex's file), with the
    # modelled measurements in the same units.
    lines = [
        HEADER.replace("per-sex summary statistics", "subjects, the measurements diffbody models")
        .replace(" (unweighted sample statistics, numpy linear percentiles)", "")
        .replace(" sd has ddof=1.", " row: 0-based row in its sex's file."),
        ",".join(("sex", "row") + SUBJECT_COLUMNS) + "\n",
    ]
    for sex, filename in FILES:
        data = read_measurements(source / filename)
        for k in range(data["stature"].size):
            values = [_fmt(data[c][k]) for c in SUBJECT_COLUMNS]
            lines.append(",".join([sex, str(k)] + values) + "\n")
    SUBJECTS.write_text("".join(lines), encoding="utf-8")
    print(f"wrote {SUBJECTS} ({len(lines) - 2} subjects)")


if __name__ == "__main__":
    main(sys.argv)
