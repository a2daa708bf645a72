"""Sphere-cloud fits (part 3 of benchmarks/anthropometry.py; runs alone too):

    python benchmarks/_sphere_cloud.py [--clouds 8] [--x64]

Synthetic clouds: the male 50th percentile body with every scale group's axial and radial
factor drawn from exp(N(0, 0.05^2)) (about the spread of adult proportions), in a random
posture (`diffbody.sample_pose`, spread 0.15: a person standing, limbs moved, the wrist
16 cm from the standard position in the median, 32 cm at the 90th percentile, segments
turned 7 degrees in the median, the whole body up to +-0.5 rad about the vertical),
measured with Gaussian noise on every number and a fraction of the spheres replaced by
outliers (`diffbody.synthetic_cloud`). Each cloud is fitted from the standard position
without correspondences. Figures: time per cloud alone and batched (compile
apart), the segment-length error (mean and max over every segment of length > 0, over
the clouds of a condition) against noise and outlier fraction, and how often a fit lands
(mean error < 2 mm, exact clouds) as postures move farther from the start (spread 0.3: the
wrist 28 cm away in the median, 54 cm at the 90th percentile).
"""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from common import goal, machine, print_goals, select_device, versions

NOISE_MM = (0, 2, 5, 10)
OUTLIERS = (0.0, 0.1, 0.2)
SCALE_SPREAD = 0.05  # log scale factor deviation


def make_clouds(db, body, seed: int, n: int, noise: float, outliers: float, spread=0.15):
    """n clouds: (centers (n, m, 3), radii (n, m), true segment lengths (n, n_seg))."""
    from diffbody.anthropometry._scaling import per_segment

    g = len(db.SCALE_GROUPS)

    def one(key):
        k_ax, k_ra, k_pose, k_cloud = jax.random.split(key, 4)
        axial = jnp.exp(SCALE_SPREAD * jax.random.normal(k_ax, (g,)))
        radial = jnp.exp(SCALE_SPREAD * jax.random.normal(k_ra, (g,)))
        person = db.scale_body(body, per_segment(body, axial), per_segment(body, radial))
        pose = db.sample_pose(body, k_pose, spread=spread)
        centers, radii, _ = db.synthetic_cloud(person, pose, k_cloud, noise, outliers)
        return centers, radii, person.lengths

    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    return jax.tree.map(np.asarray, jax.jit(jax.vmap(one))(keys))


def length_errors(fit, lengths: np.ndarray) -> np.ndarray:
    """(n, n_seg with length > 0) absolute segment-length errors (m)."""
    keep = lengths[0] > 0
    return np.abs(np.asarray(fit.body.lengths) - lengths)[:, keep]


def sphere_cloud_figures(clouds: int = 8) -> dict:
    import diffbody as db

    body = db.load_body(variant="male50")
    goals = []
    centers, radii, lengths = make_clouds(db, body, 0, max(clouds, 2), 0.005, 0.1)

    # One cloud alone: the first call compiles, then the median of three.
    t0 = time.perf_counter()
    jax.block_until_ready(db.fit_spheres(body, centers[0], radii[0]).axial)
    compile_one = time.perf_counter() - t0
    runs = []
    for i in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(db.fit_spheres(body, centers[i % 2], radii[i % 2]).axial)
        runs.append(time.perf_counter() - t0)
    alone = float(np.median(runs))
    print(f"\nsphere-cloud fit, one cloud: compile+first {compile_one:.1f} s, then {alone:.3f} s")

    # Batched: the first call compiles for the chunk size, the second is timed.
    batch = db.fit_spheres_batch(body, centers, radii, chunk_size=clouds, progress=False)
    t0 = time.perf_counter()
    batch = db.fit_spheres_batch(body, centers, radii, chunk_size=clouds, progress=False)
    batched = len(radii) / (time.perf_counter() - t0)
    print(f"batched ({len(radii)} clouds per call): {batched:.2f} clouds/s")
    goals.append(goal("sphere clouds per second, batched (CPU)", batched, 100.0, fmt=".1f"))

    print(f"\nsegment-length error (mm) without correspondences, {clouds} clouds per cell:")
    print(f"  {'noise':>6}{'outliers':>10}{'mean':>8}{'max':>8}{'converged':>11}")
    for noise in NOISE_MM:
        for frac in OUTLIERS:
            c, r, L = make_clouds(db, body, 1, clouds, noise / 1000, frac)
            fit = db.fit_spheres_batch(body, c, r, chunk_size=clouds, progress=False)
            err = length_errors(fit, L) * 1000
            ok = np.mean(np.asarray(fit.status) == db.FitStatus.CONVERGED)
            print(f"  {noise:>4} mm{frac:>9.0%}{err.mean():8.2f}{err.max():8.2f}{ok:11.0%}")
            if noise == 5 and frac == 0.1:
                goals.append(
                    goal(
                        "segment-length error, 5 mm noise, 10 % outliers (mean)",
                        float(err.mean()),
                        2.0,
                        fmt=".2f",
                        unit=" mm",
                        op="<",
                    )
                )
    del batch

    print("\nclouds fitted (mean segment-length error < 2 mm), exact clouds, by posture spread:")
    for spread in (0.15, 0.3):
        c, r, L = make_clouds(db, body, 2, clouds, 0.0, 0.0, spread=spread)
        fit = db.fit_spheres_batch(body, c, r, chunk_size=clouds, progress=False)
        landed = np.mean(length_errors(fit, L).mean(axis=1) < 0.002)
        print(f"  spread {spread}: {landed:.0%}")
    return {"goals": goals}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clouds", type=int, default=8, help="clouds per condition")
    parser.add_argument("--x64", action="store_true", help="float64 (default float32)")
    args = parser.parse_args()
    select_device("cpu", x64=args.x64)
    print(machine())
    print(versions(["jax", "jaxlib", "optimistix", "equinox", "numpy"]))
    print_goals(sphere_cloud_figures(args.clouds)["goals"], "sphere-cloud goals")


if __name__ == "__main__":
    main()
