"""Writes the command line's example input to data/webb/: example_points.csv (image points
of the default joint tree, 60 frames of the walking-like motion of the male50 body seen at
3 m by a 1000 px camera, 1 px noise), example_depth.csv (the pelvis centre's depth) and
example_skeleton.json (the default tree, as a file to copy and edit).

Run from the repository root: python data/webb/make_example.py
"""

from pathlib import Path

import jax
import numpy as np

import diffbody as db
from diffbody.images._joint_tree import default_joint_tree, write_joint_tree
from diffbody.images._motions import walking_motion
from diffbody.images._pinhole import camera_around, image_sequence

OUT = Path(__file__).resolve().parent


def main() -> None:
    jax.config.update("jax_enable_x64", True)
    body, tree = db.load_body(), default_joint_tree()
    joints = walking_motion(body, tree, 60)
    camera = camera_around([0.0, 0.0, 1.0], 3.0, 30.0, 1.2, 1000.0)
    seq = image_sequence(tree, camera, joints, 1.0, jax.random.PRNGKey(3))
    uv = np.asarray(seq.uv)
    header = ",".join(f"{n}.{c}" for n in tree.names for c in "uv")
    np.savetxt(
        OUT / "example_points.csv",
        uv.reshape(len(uv), -1),
        fmt="%.3f",
        delimiter=",",
        header=header,
        comments="",
    )
    np.savetxt(
        OUT / "example_depth.csv",
        np.asarray(seq.root_depth),
        fmt="%.6f",
        header="center_hip_depth_m",
        comments="",
    )
    write_joint_tree(tree, OUT / "example_skeleton.json")
    print("wrote example_points.csv, example_depth.csv, example_skeleton.json")


if __name__ == "__main__":
    main()
