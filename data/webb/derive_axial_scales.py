"""Writes data/webb/ansur2_axial_scales.csv: for every ANSUR II subject of an even row of the
survey's file (data/ansur2_subjects.csv; the odd rows are held out for the benchmarks), the
axial (length) scale factors of the default body of that sex scaled to all of the subject's
body measurements but weight (`diffbody.scale_population`, the prior fitted to the even rows
of that sex). The part-length prior of the image-sequence lifting
(`diffbody.images._length_prior`) is built from them for any joint tree.

Run from the repository root: python data/webb/derive_axial_scales.py
"""

from pathlib import Path

import diffbody as db
from diffbody.anthropometry._prior import ansur2_subjects

ROOT = Path(__file__).resolve().parents[2]


def main() -> None:
    names = db.MEASUREMENT_NAMES
    known = tuple(n for n in names if n != "weightkg")
    cols = [names.index(k) for k in known]
    lines = []
    for sex in ("male", "female"):
        rows, values = ansur2_subjects(sex)
        train = rows % 2 == 0
        prior = db.PopulationPrior.fit(values[train], sex=sex)
        out = db.scale_population(known, values[train][:, cols], prior=prior, progress=False)
        for row, axial in zip(rows[train], out.log_scales[:, 0]):
            lines.append(",".join([sex, str(int(row))] + [f"{v:.6f}" for v in axial]))
        print(f"{sex}: {int(train.sum())} subjects scaled")
    path = ROOT / "data/webb/ansur2_axial_scales.csv"
    with open(path, "w") as f:
        f.write("# log axial scale factors of the default body scaled to ANSUR II subjects\n")
        f.write("# (Gordon et al. 2014; even rows only); see data/README.md, data/webb\n")
        f.write(",".join(["sex", "row", *db.SCALE_GROUPS]) + "\n")
        f.write("\n".join(lines) + "\n")
    print(f"wrote {path} ({len(lines)} subjects)")


if __name__ == "__main__":
    main()
