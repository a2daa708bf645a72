"""A motion fit over time (`fit_motion`): the ISB joint angles of every frame, a small axes
per joint and side, and the marker error of every frame."""

from pathlib import Path

import numpy as np

from .._body import Body
from .._joint_angles import LIMB_JOINTS, LUMBAR_NAMES
from .._solver import FitStatus
from ._motion_result import MotionFit

JOINTS = ("hip", "knee", "ankle")  # the gait joints, drawn by default
SIDES = (("r", "right"), ("l", "left"))
# Legend names where the angle's own name does not say the motion (module `_joint_angles`:
# the ankle's is positive in dorsiflexion).
MOTIONS = {"ankle_angle": "dorsiflexion"}


def joint_groups(joints=JOINTS) -> list[tuple[str, tuple[str, ...]]]:
    """(axes title, angle names of `MotionFit.angles`) per axes: a limb joint (a prefix of
    `LIMB_JOINTS`: hip, knee, ankle, shoulder, arm, elbow) once per side, right first;
    "lumbar" once."""
    names = {prefix: angles for prefix, _, _, _, angles, _ in LIMB_JOINTS}
    groups = []
    for joint in joints:
        if joint == "lumbar":
            groups.append(("lumbar", LUMBAR_NAMES))
        elif joint in names:
            groups += [
                (f"{joint}, {side}", tuple(f"{n}_{s}" for n in names[joint])) for s, side in SIDES
            ]
        else:
            raise ValueError(
                f"draw_motion: unknown joint {joint!r}; use some of {', '.join(names)}, lumbar"
            )
    return groups


def _short(name: str, joint: str) -> str:
    """An angle's legend: its name without joint and side ("hip_flexion_r" -> "flexion"),
    or the motion it measures (`MOTIONS`)."""
    base = name[:-2] if name.endswith(("_r", "_l")) else name
    if base in MOTIONS:
        return MOTIONS[base]
    return base[len(joint) + 1 :] if base.startswith(joint + "_") else base


def draw_motion(
    fit: MotionFit,
    body: Body,
    *,
    joints=JOINTS,
    title: str | None = None,
    fig=None,
    path: str | Path | None = None,
):
    """The joint angles and the marker error of every frame of a motion fit.

    One row per joint of `joints` (`joint_groups`), right side on the left, left side on the
    right, lumbar across both: the joint's ISB angles (`MotionFit.angles`, degrees) against
    time (s). The last row: per frame the RMS of the present markers' errors
    (`MotionFit.rms`) and the largest error (`MotionFit.max`), mm; frames whose fit failed
    marked with a cross.

    Args:
        fit: `fit_motion`'s result; body: the body fitted (`StaticFit.body`).
        joints: which joints; title: over the figure.
        fig: a matplotlib Figure to draw into (empty); default a new one (Agg, no pyplot).
        path: write a PNG there too.

    Returns:
        The Figure: its axes are the groups' in `joint_groups` order (right, left per limb
        joint), then the marker error's.
    """
    from matplotlib.figure import Figure

    groups = joint_groups(joints)
    rows = [g for g in groups if not g[0].endswith(", left")]
    if fig is None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        fig = Figure(figsize=(9.0, 1.9 * (len(rows) + 1) + 0.6), layout="constrained")
        FigureCanvasAgg(fig)
    grid = fig.add_gridspec(len(rows) + 1, 2)
    t = np.asarray(fit.times, float)
    angles = fit.angles(body)
    row = 0
    first = None
    for label, names in groups:
        joint = label.split(",")[0]
        side = label.split(", ")[1] if ", " in label else None
        spot = grid[row, :] if side is None else grid[row, 0 if side == "right" else 1]
        ax = fig.add_subplot(spot, sharex=first)
        first = first or ax
        for name in names:
            ax.plot(t, angles[name], lw=1.3, label=_short(name, joint))
        ax.axhline(0.0, color="0.6", lw=0.6, zorder=0)
        ax.set_title(label, fontsize=9, loc="left")
        ax.set_ylabel("deg")
        ax.tick_params(labelsize=8, labelbottom=False)
        if side != "left":
            # Above the axes, level with the title: never over the curves.
            ax.legend(
                fontsize=7, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=len(names),
                frameon=False, borderaxespad=0.1,
            )  # fmt: skip
        if side != "right":
            row += 1
    ax = fig.add_subplot(grid[row, :], sharex=first)
    ax.plot(t, 1000.0 * np.asarray(fit.rms), color="k", lw=1.4, label="RMS")
    ax.plot(t, 1000.0 * np.asarray(fit.max), color="tab:red", lw=0.9, alpha=0.7, label="largest")
    failed = np.asarray(fit.status) == FitStatus.FAILED
    if failed.any():
        y = np.nan_to_num(1000.0 * np.asarray(fit.rms)[failed])
        ax.plot(t[failed], y, "x", color="tab:red", ms=7, label="fit failed")
    ax.set_ylim(bottom=0.0)
    ax.set_title("marker error per frame", fontsize=9, loc="left")
    ax.set_ylabel("mm")
    ax.set_xlabel("time (s)")
    ax.tick_params(labelsize=8)
    ax.legend(
        fontsize=7, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=3, frameon=False,
        borderaxespad=0.1,
    )  # fmt: skip
    if title:
        fig.suptitle(title, fontsize=10)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig
