"""Writes data/webb/walk1_joints.csv: the default joint tree's joint centres in every frame
of the OpenSim example walk (data/mocap/subject01_walk1.trc, knees and ankles calibrated on
subject01_static.trc), by `diffbody.images._joint_centres.joint_centres_from_markers`.

Run from the repository root: python data/webb/derive_walk_joints.py
"""

from pathlib import Path

import numpy as np

from diffbody.files._trc import read_trc
from diffbody.images._joint_centres import NAMES, joint_centres_from_markers

ROOT = Path(__file__).resolve().parents[2]


def main() -> None:
    walk = read_trc(ROOT / "data/mocap/subject01_walk1.trc")
    static = read_trc(ROOT / "data/mocap/subject01_static.trc")
    joints = joint_centres_from_markers(walk, static)
    header = ["frame", "time_s"] + [f"{n}.{c}" for n in NAMES for c in "xyz"]
    rows = np.concatenate(
        [
            np.arange(1, walk.n_frames + 1)[:, None],
            walk.times[:, None],
            joints.reshape(walk.n_frames, -1),
        ],
        axis=1,
    )
    out = ROOT / "data/webb/walk1_joints.csv"
    with open(out, "w") as f:
        f.write(
            "# joint centres (m, world frame X forward, Y left, Z up) of the OpenSim example walk\n"
        )
        f.write("# subject01_walk1.trc (60 Hz); see data/README.md, section data/webb\n")
        f.write(",".join(header) + "\n")
        for r in rows:
            f.write(",".join([str(int(r[0])), f"{r[1]:.6f}"] + [f"{v:.6f}" for v in r[2:]]) + "\n")
    print(f"wrote {out} ({walk.n_frames} frames, {len(NAMES)} joints)")


if __name__ == "__main__":
    main()
