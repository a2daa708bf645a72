"""Pictures of image-sequence analysis (seed 003) with matplotlib: a recovered skeleton over
its image points, Webb's lower bounds rising frame by frame, and the reprojection error of
every frame."""

from pathlib import Path

import numpy as np

from ._joint_tree import JointTree


def draw_lifting(
    tree: JointTree,
    uv,
    joints,
    focal: float,
    path: str | Path | None = None,
    frames=None,
    truth=None,
    title: str | None = None,
):
    """The recovered skeleton over the image points: for a few `frames` (default four
    spread over the sequence), the image (observed points as dots, the recovered 3D
    joints (T, J, 3) reprojected as lines) and the same frames seen from above (camera x
    across, depth z up; `truth` (T, J, 3) dashed when given). Writes `path` when given;
    returns the figure."""
    import matplotlib.pyplot as plt

    uv, joints = np.asarray(uv), np.asarray(joints)
    T = len(uv)
    frames = (
        np.unique(np.linspace(0, T - 1, min(4, T)).round().astype(int))
        if frames is None
        else np.asarray(frames)
    )
    fig, axes = plt.subplots(2, len(frames), figsize=(3.2 * len(frames), 7.0), squeeze=False)
    s, e = np.asarray(tree.part_start), np.asarray(tree.part_end)
    for col, t in enumerate(frames):
        ax = axes[0, col]
        z = np.maximum(joints[t, :, 2], 1e-6)
        proj = focal * joints[t, :, :2] / z[:, None]
        for a, b in zip(s, e):
            ax.plot(proj[[a, b], 0], proj[[a, b], 1], "-", color="tab:blue", lw=2)
        ax.plot(uv[t, :, 0], uv[t, :, 1], "o", color="tab:orange", ms=4, label="image points")
        ax.plot(uv[t, tree.root, 0], uv[t, tree.root, 1], "s", color="k", ms=5, label="reference")
        ax.set_aspect("equal")
        ax.invert_yaxis()  # image v points down
        ax.set_title(f"frame {t}: image (px)")
        ax.set_xlabel("u")
        if col == 0:
            ax.set_ylabel("v")
            ax.legend(loc="lower left", fontsize=7)
        ax = axes[1, col]
        for a, b in zip(s, e):
            ax.plot(joints[t, [a, b], 0], joints[t, [a, b], 2], "-", color="tab:blue", lw=2)
            if truth is not None:
                tr = np.asarray(truth)
                ax.plot(tr[t, [a, b], 0], tr[t, [a, b], 2], "--", color="tab:gray", lw=1)
        ax.set_aspect("equal")
        ax.set_title("from above (m)" + (", truth dashed" if truth is not None else ""))
        ax.set_xlabel("camera x")
        if col == 0:
            ax.set_ylabel("depth z")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=90)
        plt.close(fig)
    return fig


def reprojection_errors(uv, joints, focal) -> np.ndarray:
    """(T,) px: per frame the RMS over the joints of the distance between the image points
    `uv` (T, J, 2) px and the joints (T, J, 3) m, camera frame, projected through the
    pinhole of focal length `focal` px. Their RMS over the frames is
    `Lifting.reprojection_rms`."""
    uv, joints = np.asarray(uv, float), np.asarray(joints, float)
    z = np.maximum(joints[..., 2], 1e-3)  # as the refinement has it: never behind the camera
    err = float(focal) * joints[..., :2] / z[..., None] - uv
    return np.sqrt(np.mean(np.sum(err * err, axis=-1), axis=-1))


def draw_bounds(
    tree: JointTree,
    bounds,
    true_lengths=None,
    path: str | Path | None = None,
    ax=None,
    *,
    lengths=None,
):
    """Webb's lower bounds (T, P) (m) frame by frame, one line per part; the final lengths
    (P,) m dashed at the right when given (e.g. `Lifting.lengths`, the refinement's), the
    true lengths dotted when given: the seed's idea, bounds rising until the part is seen
    perpendicular to its ray (and falling to zero when a part above it changes)."""
    import matplotlib.pyplot as plt

    bounds = np.asarray(bounds)
    if ax is None:
        fig, ax = plt.subplots(figsize=(9, 5), layout="constrained")
    else:
        fig = ax.figure
    colours = plt.cm.tab20(np.linspace(0, 1, tree.n_parts))
    T = len(bounds)
    for k, name in enumerate(tree.part_names):
        ax.plot(bounds[:, k], color=colours[k], lw=1.5, label=name.split("->")[1])
        if true_lengths is not None:
            ax.axhline(float(np.asarray(true_lengths)[k]), color=colours[k], ls=":", lw=1)
        if lengths is not None:  # over the last tenth of the frames and past the end
            y = float(np.asarray(lengths)[k])
            ax.plot([0.9 * (T - 1), 1.04 * (T - 1)], [y, y], color=colours[k], ls="--", lw=1.5)
    ax.set_xlabel("frame")
    ax.set_ylabel("lower bound on the length (m)")
    keys = [
        k
        for k, given in (("dashed: final", lengths), ("dotted: true", true_lengths))
        if given is not None
    ]
    title = "part ending at" + (f" ({', '.join(keys)})" if keys else "")
    # Beside the axes: the bounds fill the whole height.
    ax.legend(
        fontsize=7, title=title, title_fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0)
    )
    if path is not None:
        fig.savefig(path, dpi=90)
        plt.close(fig)
    return fig


def draw_sequence_fit(
    tree: JointTree,
    bounds,
    uv,
    joints,
    focal,
    *,
    lengths=None,
    true_lengths=None,
    title: str | None = None,
    path: str | Path | None = None,
):
    """An image sequence's analysis over its frames: above, each part's lower bound on its
    length (`draw_bounds`: Webb's bounds (T, P) m, the final `lengths` (P,) m dashed);
    below, the reprojection error of the recovered `joints` (T, J, 3) m, camera frame,
    against the image points `uv` (T, J, 2) px (`reprojection_errors`), with its RMS over
    all frames dotted. Writes `path` when given; returns the figure."""
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(
        2, 1, figsize=(10, 7.5), sharex=True, height_ratios=(2.2, 1), layout="constrained"
    )
    draw_bounds(tree, bounds, true_lengths, ax=top, lengths=lengths)
    top.set_xlabel("")
    errors = reprojection_errors(uv, joints, focal)
    bottom.plot(errors, color="k", lw=1.3, label="per frame")
    rms = float(np.sqrt(np.mean(errors**2)))
    bottom.axhline(rms, color="tab:red", ls=":", lw=1.2, label=f"RMS {rms:.2f} px")
    bottom.set_ylim(bottom=0.0)
    bottom.set_xlabel("frame")
    bottom.set_ylabel("reprojection error (px)")
    bottom.legend(fontsize=7, loc="upper right")
    if title:
        fig.suptitle(title)
    if path is not None:
        fig.savefig(path, dpi=90)
        plt.close(fig)
    return fig
