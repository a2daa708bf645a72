"""The image-sequence benchmark's figures beyond one camera (called by benchmarks/webb.py):
several calibrated cameras (`diffbody.lift_views`) and the depth signs of the one-camera
pipeline.

Views: the same synthetic walk and reach of the default body and the same semi-real walk as
the one-camera table, each seen by two (or three) pinhole cameras 3 m away at 1.2 m height,
focal 1000 px, 90 degrees apart (azimuths 20 and 110; the third at 200), with Gaussian pixel
noise. Figures: the mean over parts of |L / L_true - 1| (the semi-real truth is each part's
median over the trial), MPJPE (world frame, absolute: no alignment), and beside it the
MPJPE of the triangulation the fit starts from.

Depth signs: a part's depth sign is whether its end lies farther from the camera than its
start (camera z). Counted per part over the frames where the truth's two ends differ in
depth by more than 1 cm (where they do not, the sign does not change the posture).
"""

import statistics

import jax
import jax.numpy as jnp
import numpy as np

VIEW_AZIMUTHS = (20.0, 110.0, 200.0)
DEPTH_APART = 0.01  # m


def depth_signs(tree, joints, truth) -> np.ndarray:
    """(P,) per part, the share of frames (over every sequence) whose depth sign matches
    the truth's, among those whose true ends differ in depth by > `DEPTH_APART`; nan for a
    part that never does. joints, truth: (..., T, J, 3) camera frame."""
    s, e = list(tree.part_start), list(tree.part_end)
    dz = np.asarray(joints)[..., e, 2] - np.asarray(joints)[..., s, 2]
    dz_true = np.asarray(truth)[..., e, 2] - np.asarray(truth)[..., s, 2]
    seen = np.abs(dz_true) > DEPTH_APART
    right = (np.sign(dz) == np.sign(dz_true)) & seen
    axes = tuple(range(dz.ndim - 1))
    with np.errstate(invalid="ignore"):
        return right.sum(axes) / seen.sum(axes)


def _cameras(world, n_views: int, focal: float, distance: float, height: float, root: int = 0):
    from diffbody.images._pinhole import camera_around

    centre = np.asarray(world)[:, root].mean(0)
    return [
        camera_around([centre[0], centre[1], 1.0], distance, az, height, focal)
        for az in VIEW_AZIMUTHS[:n_views]
    ]


def seen_by(cams, world, noise: float, key, dtype):
    """(V, T, J, 2) px: world joints (T, J, 3) in each camera, with Gaussian noise."""
    from diffbody.images._pinhole import project, to_camera

    uv = jnp.stack([project(to_camera(c, jnp.asarray(world)), c.focal) for c in cams])
    return (uv + noise * jax.random.normal(key, uv.shape, uv.dtype)).astype(dtype)


def views_cell(tree, worlds, truth_lengths, n_views, noise, key, dtype, geometry):
    """(length error %, MPJPE mm, triangulation MPJPE mm) over the worlds (T, J, 3) each
    seen by `n_views` cameras; `geometry`: (focal, distance, height)."""
    import diffbody as db
    from diffbody.images._views import stack_cameras, triangulate

    rel, mpjpe, tri = [], [], []
    for i, world in enumerate(worlds):
        cams = _cameras(world, n_views, *geometry, tree.root)
        uv = seen_by(cams, world, noise, jax.random.fold_in(key, i), dtype)
        out = db.lift_views(tree, cams, uv)
        rel.append(np.abs(np.asarray(out.lengths) / truth_lengths - 1).mean() * 100)
        mpjpe.append(np.linalg.norm(np.asarray(out.joints) - world, axis=-1).mean() * 1e3)
        X = np.asarray(triangulate(stack_cameras(cams), uv))
        tri.append(np.linalg.norm(X - world, axis=-1).mean() * 1e3)
    return float(np.mean(rel)), float(np.mean(mpjpe)), float(np.mean(tri))


def views_speed(tree, world, n: int, repeats: int, key, dtype, geometry):
    """(first call s, median warm s) of `lift_views` on a batch of n noisy (1 px) two-view
    sequences of one world (T, J, 3)."""
    import time

    import diffbody as db

    cams = _cameras(world, 2, *geometry, tree.root)
    uv = jnp.stack([seen_by(cams, world, 1.0, jax.random.fold_in(key, i), dtype) for i in range(n)])

    def call():
        t0 = time.perf_counter()
        jax.block_until_ready(db.lift_views(tree, cams, uv))
        return time.perf_counter() - t0

    first = call()
    return first, statistics.median(call() for _ in range(repeats))


def add_views(run, tree, cells: dict, n: int, repeats: int, key, dtype, geometry, quick: bool):
    """The views table, the depth-sign table and the speed of `lift_views` into `run`; the
    goals they measure. `cells`: {data: (worlds, truth lengths, one-camera depth signs)} at
    the goals' frames and 1 px."""
    from common import goal, ms

    views = run.table(
        "views",
        ["data, frames, 1 px", "cameras", "length error", "MPJPE", "triangulation MPJPE"],
        "lrrrr",
    )
    goals = []
    print("\nseveral calibrated cameras (`lift_views`), 1 px")
    for data, (worlds, truth, _) in cells.items():
        T = len(worlds[0])
        for n_views in (2, 3):
            rel, mpjpe, tri = views_cell(tree, worlds, truth, n_views, 1.0, key, dtype, geometry)
            print(
                f"  {data:<11} {T:>4} frames  {n_views} cameras  lengths {rel:.2f} %  "
                f"MPJPE {mpjpe:.1f} mm (triangulated {tri:.1f} mm)"
            )
            views.add(f"{data}, {T}", n_views, f"{rel:.2f} %", f"{mpjpe:.1f} mm", f"{tri:.1f} mm")
            if n_views == 2:
                what = f"two calibrated cameras, {data}, 1 px, {T} frames"
                goals.append(goal(f"length error, {what}", rel, 1.0, fmt=".2f", unit=" %", op="<"))
                goals.append(goal(f"MPJPE, {what}", mpjpe, 10.0, fmt=".1f", unit=" mm", op="<"))
    signs = run.table(
        "depth-signs",
        [
            "part (one camera, `lift`, 1 px)",
            *(f"{data}, {len(w[0])} frames" for data, (w, _, _) in cells.items()),
        ],
        "l" + "r" * len(cells),
    )
    names = tree.names
    print("\ndepth signs right, one camera (`lift`), per part:")
    for k in range(tree.n_parts):
        part = f"{names[tree.part_start[k]]} - {names[tree.part_end[k]]}"
        shares = [c[2][k] for c in cells.values()]
        text = ["-" if np.isnan(x) else f"{x:.0%}" for x in shares]
        signs.add(part, *text)
        print(f"  {part:<28} " + "  ".join(f"{t:>5}" for t in text))
    first, warm = views_speed(tree, cells["synthetic"][0][0], n, repeats, key, dtype, geometry)
    speed = run.table(
        "views-speed",
        ["two calibrated cameras, batch of sequences", "first call (s)", "run (ms)", "sequences/s"],
        "lrrr",
    )
    frames = len(cells["synthetic"][0][0])
    speed.add(f"`lift_views`, {n} of {frames} frames", f"{first:.1f}", ms(warm), f"{n / warm:,.0f}")
    print(
        f"  lift_views, {n} sequences of {frames} frames: first call {first:.1f} s, "
        f"run {warm * 1e3:.1f} ms, {n / warm:,.0f} sequences/s"
    )
    return goals
