"""Peer inverse-kinematics libraries on diffbody's left arm: IKPy and pytorch_kinematics.

Both peers solve the same problem as diffbody's reach benchmark: put the palm
(`left_hand.palm`) of the default body on a world position by moving the left arm, i.e. the
nine hinges of `export_urdf(body, ..., chain=("left_upper_arm", "left_hand"))`
(`{seg}_theta` about z, `{seg}_phi` about y, `{seg}_twist` about z for the upper arm,
forearm and hand), with everything above the arm (trunk, clavicle) held at the rest pose.

The chain. `arm_chain` exports that URDF and adds a fixed tip link `palm` (joint
`palm_fixed`, child of `left_hand`) at the palm feature: the hand has no twist range, so the
palm is rigid in the hand's link frame, and both peers can aim that link at the target. The
URDF hangs from link `base`, the clavicle's twisted frame at its proximal joint; targets are
mapped from the world into it with the rest pose's clavicle frame (`ArmChain.to_base`) and
answers back out (`ArmChain.to_world`).

What the peers do not know. URDF joint limits are boxes, and the exported ones (theta in
[-pi, pi], phi in [0, pi], twist in [-2 pi, 2 pi]) only keep the angles in range: diffbody's
anatomical limits live in swing space (a box and a cone on the swing vector, a hinge plane,
a twist range) and cannot be written in URDF. The peers therefore solve a *looser* problem
than diffbody, which must stay within the anatomical limits: any error gap in their favour
partly comes from that.

What is measured, for each peer (`PeerResult`):

- `reached`: the palm position of the peer's answer by the peer's *own* forward kinematics
  (IKPy's `forward_kinematics`; pytorch_kinematics' `forward_kinematics` of a float64 copy
  of its chain, so that float32 rounding in the evaluation does not count as solver error,
  though its URDF loader keeps the joint origins rounded to float32: a few 1e-8 m at the
  palm), in the world; `errors` = its distance to the target (m). `joint_values` holds the
  answers themselves.
- `setup_s`: building the chain from the URDF plus one warm-up solve (the peers' equivalent
  of diffbody's compile time); `run_s`: solving all targets after that, timed with
  `time.perf_counter`; `solves_per_s` = targets / run_s.

Every target starts from the same seed, the rest pose's joint values (`rest_joint_values`),
not from the previous answer. Settings (also in `PeerResult.settings`):

- IKPy (`solve_ikpy`): one target at a time in a Python loop, `Chain.inverse_kinematics`
  with its defaults: position only, NumPy backend, `scipy.optimize.least_squares` (trust
  region reflective, finite-difference Jacobian, SciPy's default tolerances and budget)
  within the URDF bounds. IKPy moves a seed lying on a bound 1e-3 rad inside it.
- pytorch_kinematics (`solve_pytorch_kinematics`): its batched damped-least-squares solver
  `PseudoInverseIK`, float32 on the CPU (on a CUDA GPU for `ik.py --device gpu`), all
  targets at once, `PK_RETRIES` starting configurations per target (the seed, then
  configurations drawn uniformly within the URDF limits with a fixed torch seed: its API's
  way of escaping poor seeds, see below), at most
  `PK_MAX_ITERATIONS` iterations, position only (orientation weight 0, orientation
  tolerance infinite), a problem stops once any start is within `PK_POS_TOLERANCE`; its
  library defaults otherwise (learning rate 1, Levenberg-Marquardt damping 0.1, joint
  limits from the URDF enforced by its final wrap-clamp-refine pass). Its early stop on "no
  improvement" is off: it watches the full pose error, so it would stop a position-only
  problem on its (ignored) orientation error. The answer of a target is its start with the
  smallest position error. Torch runs on `PK_THREADS` intra-op thread(s) by default: the
  tensors are tiny (a batch of 4x4 matrices), and on small or shared machines torch's
  default thread pool can be a hundred times slower than one thread.

The seed is a hard start for both peers: at rest every arm segment hangs along its socket's
-Z, so phi = pi, which is both the upper bound of phi in the URDF and the pole of the
z-y-z hinges (theta and twist turn about the same axis). IKPy's bounded least squares often
stops there against the phi bound (a swing the other way needs phi > pi); pytorch_kinematics
gets out through its random starts. The figures include this on purpose: the rest pose is
also `solve_reach`'s default start, where it is an ordinary point (swing vector zero).

Run `python benchmarks/peers.py` for a self-check: the URDF+palm forward kinematics of both
peers matches diffbody's palm to 1e-6 m at a random pose, then both peers solve 200
reachable targets (random arm poses within diffbody's anatomical limits).
"""

import argparse
import contextlib
import importlib.metadata
import io
import math
import re
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import diffbody

ARM = ("left_upper_arm", "left_hand")  # the exported chain, first and last segment
EFFECTOR = "left_hand.palm"
PARENT = "left_clavicle"  # whose frame is the URDF's `base` link
BASE_LINK = "base"
TIP_LINK = "palm"

PK_RETRIES = 4  # the fewest that reach every target of the self-check (1: 55%, 2: 82%)
PK_MAX_ITERATIONS = 50  # the self-check's problems all stop within 30
PK_POS_TOLERANCE = 1e-5  # m: well under the 1 mm that counts as reached, so answers refine
PK_THREADS = 1

# Compiled once: JAX's op-by-op dispatch of a whole-body `forward` takes seconds.
_forward = eqx.filter_jit(diffbody.forward)


@dataclass(frozen=True)
class ArmChain:
    """The exported left arm, and where its `base` link sits in the world at rest."""

    urdf: Path
    joint_names: tuple[str, ...]  # the nine revolute joints, root to tip
    R_world_base: np.ndarray  # (3, 3): columns are the base link's axes in the world
    origin: np.ndarray  # (3,): the base link's origin in the world (m)
    palm_offset: np.ndarray  # (3,): the palm in the `left_hand` link frame (m)
    limits: np.ndarray  # (9, 2): the URDF's (lower, upper) of each joint (rad)
    base_link: str = BASE_LINK
    tip_link: str = TIP_LINK

    def to_base(self, points_world: np.ndarray) -> np.ndarray:
        """World points (..., 3) in the base link's frame."""
        return (np.asarray(points_world) - self.origin) @ self.R_world_base

    def to_world(self, points_base: np.ndarray) -> np.ndarray:
        """Base-frame points (..., 3) in the world."""
        return np.asarray(points_base) @ self.R_world_base.T + self.origin


@dataclass(frozen=True)
class PeerResult:
    """One peer's answers to a batch of palm targets (see the module docstring)."""

    name: str
    version: str
    settings: str
    joint_values: np.ndarray  # (n, 9): the answers, in `ArmChain.joint_names` order (rad)
    reached: np.ndarray  # (n, 3): the palm at the answer, world (m)
    errors: np.ndarray  # (n,): distance from the target (m)
    setup_s: float
    run_s: float
    solves_per_s: float

    def success(self, tol: float = 1e-3) -> float:
        """Fraction of targets reached within `tol` (m)."""
        return float(np.mean(self.errors <= tol))


def _result(
    package: str,
    settings: str,
    q: np.ndarray,
    reached: np.ndarray,
    targets_world: np.ndarray,
    setup_s: float,
    run_s: float,
) -> PeerResult:
    """A peer's answers with their errors and rate (`package`: its PyPI name)."""
    return PeerResult(
        name=package.replace("-", "_"),
        version=importlib.metadata.version(package),
        settings=settings,
        joint_values=q,
        reached=reached,
        errors=np.linalg.norm(reached - targets_world, axis=-1),
        setup_s=setup_s,
        run_s=run_s,
        solves_per_s=len(targets_world) / run_s,
    )


def _xml_float(*values: float) -> str:
    """Numbers as XML text, each exactly as the float64 it is."""
    return " ".join(repr(float(v)) for v in values)


def arm_chain(body: diffbody.Body, directory: str | Path) -> ArmChain:
    """Export the left arm of `body` as `directory/left_arm.urdf`, with a fixed tip link at
    the palm, and return it with its placement in the world at the rest pose."""
    fk = _forward(body, body.rest_pose())
    parent, hand = body.segment_index(PARENT), body.segment_index("left_hand")
    R_world_base = np.asarray(fk.R_world_twisted[parent], np.float64)
    origin = np.asarray(fk.joint_positions[body.proximal_joint[parent]], np.float64)
    R_world_hand = np.asarray(fk.R_world_twisted[hand], np.float64)
    wrist = np.asarray(fk.joint_positions[body.proximal_joint[hand]], np.float64)
    palm = np.asarray(fk.feature_points[body.feature_index(EFFECTOR)], np.float64)
    palm_offset = R_world_hand.T @ (palm - wrist)

    path = Path(directory) / "left_arm.urdf"
    diffbody.export_urdf(body, path, chain=ARM)
    # Keep the exporter's comment (it says how to set the joints): ET drops comments unless told.
    tree = ET.parse(path, ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    robot = tree.getroot()
    ET.SubElement(robot, "link", name=TIP_LINK)
    joint = ET.SubElement(robot, "joint", name=f"{TIP_LINK}_fixed", type="fixed")
    ET.SubElement(joint, "parent", link="left_hand")
    ET.SubElement(joint, "child", link=TIP_LINK)
    ET.SubElement(joint, "origin", xyz=_xml_float(*palm_offset), rpy="0 0 0")
    ET.indent(tree)
    tree.write(path, encoding="utf-8", xml_declaration=True)

    names = tuple(diffbody.urdf_joint_values(body, body.rest_pose(), chain=ARM))
    limits = np.array(
        [
            [float(robot.find(f"joint[@name='{name}']/limit").get(k)) for k in ("lower", "upper")]
            for name in names
        ]
    )
    return ArmChain(path, names, R_world_base, origin, palm_offset, limits)


def joint_vector(chain: ArmChain, values: dict[str, float]) -> np.ndarray:
    """`urdf_joint_values`'s dict as a vector in the chain's joint order."""
    return np.array([values[name] for name in chain.joint_names], np.float64)


def rest_joint_values(body: diffbody.Body, chain: ArmChain) -> np.ndarray:
    """The rest pose's joint values (rad), in the chain's joint order: the peers' seed.

    Clipped into the URDF limits: the rest phi is pi, the upper limit, and a float32 body
    rounds it to just above (IKPy would warn and clip it itself)."""
    values = joint_vector(chain, diffbody.urdf_joint_values(body, body.rest_pose(), chain=ARM))
    return np.clip(values, chain.limits[:, 0], chain.limits[:, 1])


# --- IKPy -----------------------------------------------------------------------------------
def _ikpy_chain(chain: ArmChain):
    from ikpy.chain import Chain

    # IKPy's links: its own origin link, the nine hinges, the fixed palm joint.
    mask = [False] + [True] * len(chain.joint_names) + [False]
    return Chain.from_urdf_file(
        str(chain.urdf), base_elements=[chain.base_link], active_links_mask=mask, name="left_arm"
    )


def _ikpy_full(q: np.ndarray) -> np.ndarray:
    """IKPy's joint vector (one entry per link, inactive ones included) from the nine."""
    return np.concatenate([[0.0], q, [0.0]])


def ikpy_palm(ik_chain, chain: ArmChain, q: np.ndarray) -> np.ndarray:
    """The palm in the world at joint values q (9,), by IKPy's forward kinematics."""
    return chain.to_world(ik_chain.forward_kinematics(_ikpy_full(q))[:3, 3])


def solve_ikpy(chain: ArmChain, targets_world: np.ndarray, seed_q: np.ndarray) -> PeerResult:
    """Solve every palm target with IKPy, one at a time from `seed_q` (module docstring)."""
    targets = chain.to_base(np.asarray(targets_world, np.float64))
    seed = _ikpy_full(np.asarray(seed_q, np.float64))
    t0 = time.perf_counter()
    ik_chain = _ikpy_chain(chain)
    ik_chain.inverse_kinematics(targets[0], initial_position=seed)
    setup_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    answers = [ik_chain.inverse_kinematics(t, initial_position=seed) for t in targets]
    run_s = time.perf_counter() - t0

    q = np.stack([full[1:-1] for full in answers])
    reached = np.stack([ikpy_palm(ik_chain, chain, qi) for qi in q])
    return _result(
        "ikpy",
        "one target at a time from the seed; inverse_kinematics defaults: position "
        "only, NumPy backend, scipy least_squares (TRF, finite differences, default tolerances)",
        q,
        reached,
        targets_world,
        setup_s,
        run_s,
    )


# --- pytorch_kinematics ---------------------------------------------------------------------
# pytorch_kinematics' bundled urdf_parser_py predates the optional `name` of <visual> and
# <collision> (valid URDF) and prints one line per sphere of the arm: drop just those lines.
_PK_PARSER_NOISE = re.compile(r'Unknown attribute "name" in .*/(visual|collision)\[\d+\]')


def _pk_chain(chain: ArmChain, dtype):
    """The chain as a pytorch_kinematics `SerialChain` in `dtype`. Its URDF loader builds
    every joint origin in float32 whatever `dtype`: in float64 its palm still differs from
    diffbody's by a few 1e-8 m."""
    import pytorch_kinematics as pk

    messages = io.StringIO()
    with contextlib.redirect_stderr(messages):
        serial = pk.build_serial_chain_from_urdf(
            chain.urdf.read_bytes(), end_link_name=chain.tip_link, root_link_name=chain.base_link
        )
    for line in messages.getvalue().splitlines():
        if not _PK_PARSER_NOISE.fullmatch(line):
            print(line, file=sys.stderr)
    names = tuple(serial.get_joint_parameter_names(exclude_fixed=True))
    if names != chain.joint_names:
        raise ValueError(f"pytorch_kinematics orders the joints {names}, not {chain.joint_names}")
    return serial.to(dtype=dtype)


def pk_palm(pk_chain, chain: ArmChain, q: np.ndarray) -> np.ndarray:
    """The palm in the world at joint values q (..., 9), by pytorch_kinematics' forward
    kinematics (in `pk_chain`'s dtype)."""
    import torch

    th = torch.as_tensor(np.reshape(q, (-1, len(chain.joint_names))), dtype=pk_chain.dtype)
    p = pk_chain.forward_kinematics(th).get_matrix()[:, :3, 3].double().numpy()
    return chain.to_world(p.reshape(np.shape(q)[:-1] + (3,)))


def solve_pytorch_kinematics(
    chain: ArmChain,
    targets_world: np.ndarray,
    seed_q: np.ndarray,
    *,
    retries: int = PK_RETRIES,
    max_iterations: int = PK_MAX_ITERATIONS,
    threads: int | None = PK_THREADS,
    device: str = "cpu",
) -> PeerResult:
    """Solve all palm targets at once with pytorch_kinematics' `PseudoInverseIK` (float32,
    on torch `device`: "cpu" or "cuda"), from `seed_q` and `retries - 1` random starts
    within the URDF limits, on `threads` torch CPU threads (None: torch's current setting);
    see the module docstring."""
    import pytorch_kinematics as pk
    import torch

    dtype = torch.float32
    targets = chain.to_base(np.asarray(targets_world, np.float64))
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(threads or previous_threads)
    try:
        t0 = time.perf_counter()
        pk_chain = _pk_chain(chain, dtype).to(device=device)
        low, high = pk_chain.low.cpu(), pk_chain.high.cpu()
        generator = torch.Generator().manual_seed(0)
        starts = torch.cat(
            [
                torch.as_tensor(seed_q, dtype=dtype)[None],
                low + (high - low) * torch.rand(retries - 1, len(low), generator=generator),
            ]
        ).to(device)
        low, high = low.to(device), high.to(device)
        solver = pk.PseudoInverseIK(
            pk_chain,
            retry_configs=starts,
            joint_limits=torch.stack([low, high], dim=-1),
            max_iterations=max_iterations,
            pos_tolerance=PK_POS_TOLERANCE,
            rot_tolerance=math.inf,
            orientation_weight=0.0,
            early_stopping_any_converged=True,
            early_stopping_no_improvement=None,
        )

        def solve(points: np.ndarray) -> np.ndarray:
            pos = torch.as_tensor(points, dtype=dtype, device=device)
            goal = pk.Transform3d(pos=pos, dtype=dtype, device=device)
            sol = solver.solve(goal)
            best = sol.err_pos.argmin(dim=1)
            # Copying the answers to the host waits for the device.
            return sol.solutions[torch.arange(len(points), device=device), best].double().cpu()

        solve(targets[:1])
        setup_s = time.perf_counter() - t0

        t0 = time.perf_counter()
        q = solve(targets).numpy()
        run_s = time.perf_counter() - t0
        used_threads = torch.get_num_threads()
        where = (
            f"CPU ({used_threads} thread(s))"
            if torch.device(device).type == "cpu"
            else torch.cuda.get_device_name(torch.device(device))
        )
    finally:
        torch.set_num_threads(previous_threads)

    reached = pk_palm(_pk_chain(chain, torch.float64), chain, q)
    return _result(
        "pytorch-kinematics",
        f"PseudoInverseIK, float32, {where}, all targets at "
        f"once; {retries} starts (seed + uniform in URDF limits), <= {max_iterations} "
        f"iterations, position only, tolerance {PK_POS_TOLERANCE:g} m, library defaults "
        "otherwise",
        q,
        reached,
        targets_world,
        setup_s,
        run_s,
    )


# --- self-check -----------------------------------------------------------------------------
def arm_poses(body: diffbody.Body, n: int, rng: np.random.Generator) -> diffbody.Pose:
    """n random poses (batched arrays) that move only the left arm (upper arm, forearm,
    hand), each segment's swing uniform in its limit box pulled into its cone, its twist
    uniform in its range: within diffbody's anatomical limits. The rest is the rest pose."""
    rest = body.rest_pose()
    arm = np.array([body.segment_index(s) for s in ("left_upper_arm", "left_forearm", "left_hand")])
    lo, hi = np.asarray(body.swing_lo)[arm], np.asarray(body.swing_hi)[arm]
    w = lo + (hi - lo) * rng.uniform(size=(n, len(arm), 2))
    smax = np.asarray(body.swing_max)[arm]
    w *= np.minimum(1.0, smax / np.maximum(np.linalg.norm(w, axis=-1), 1e-300))[..., None]
    tlo, thi = np.asarray(body.twist_lo)[arm], np.asarray(body.twist_hi)[arm]
    tau = tlo + (thi - tlo) * rng.uniform(size=(n, len(arm)))

    def one(w_arm: jax.Array, tau_arm: jax.Array) -> jax.Array:
        swing = diffbody.swing_vector(body, rest.angles).at[arm].set(w_arm)
        twist = rest.angles[:, 2].at[arm].set(tau_arm)  # column 2: tau
        # Only the arm's rows: elsewhere keep the rest angles exactly (theta is free at a pole).
        return rest.angles.at[arm].set(diffbody.angles_from_swing(body, swing, twist)[arm])

    angles = eqx.filter_jit(jax.vmap(one))(jnp.asarray(w), jnp.asarray(tau))
    return diffbody.Pose(position=jnp.broadcast_to(rest.position, (n, 3)), angles=angles)


def palm_positions(body: diffbody.Body, poses: diffbody.Pose) -> np.ndarray:
    """The palm in the world (n, 3) for batched poses, by diffbody's forward kinematics."""
    f = body.feature_index(EFFECTOR)
    return np.asarray(jax.vmap(lambda p: _forward(body, p).feature_points[f])(poses))


def _check_fk(body: diffbody.Body, chain: ArmChain, rng: np.random.Generator) -> None:
    """Both peers' URDF+palm forward kinematics against diffbody's palm at a random pose."""
    import torch

    parent = body.segment_index(PARENT)
    root = ET.parse(chain.urdf).getroot()
    first = root.find(f"joint[@name='{chain.joint_names[0]}']/origin")
    socket = np.array([float(x) for x in first.get("xyz").split()])
    length = float(body.lengths[parent])
    print(f"URDF {chain.joint_names[0]} origin in base: {socket} (clavicle length {length})")
    assert np.allclose(socket, [0.0, 0.0, length], atol=1e-12)

    pose = jax.tree.map(lambda x: x[0], arm_poses(body, 1, rng))
    assert bool(np.all(diffbody.within_limits(body, pose)))
    q = joint_vector(chain, diffbody.urdf_joint_values(body, pose, chain=ARM))
    expected = palm_positions(body, jax.tree.map(lambda x: x[None], pose))[0]
    got = {
        "ikpy": ikpy_palm(_ikpy_chain(chain), chain, q),
        "pytorch_kinematics": pk_palm(_pk_chain(chain, torch.float64), chain, q),
    }
    for name, p in got.items():
        err = float(np.linalg.norm(p - expected))
        print(f"FK check {name:>18}: |palm - diffbody palm| = {err:.2e} m")
        assert err < 1e-6, (name, p, expected)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--targets", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    body = diffbody.load_body()
    rng = np.random.default_rng(args.seed)
    with tempfile.TemporaryDirectory() as directory:
        chain = arm_chain(body, directory)
        _check_fk(body, chain, rng)
        targets = palm_positions(body, arm_poses(body, args.targets, rng))
        seed_q = rest_joint_values(body, chain)
        print(f"seed (rest pose) joint values: {np.round(seed_q, 4)}")
        print(f"{args.targets} targets: palm of random left-arm poses within diffbody's limits")
        header = ("peer", "version", "<=1mm", "median m", "solves/s", "setup s")
        print(" ".join(f"{h:>{w}}" for h, w in zip(header, (18, 8, 6, 9, 9, 8))))
        for solve in (solve_ikpy, solve_pytorch_kinematics):
            r = solve(chain, targets, seed_q)
            print(
                f"{r.name:>18} {r.version:>8} {r.success():>6.1%} {np.median(r.errors):>9.2e} "
                f"{r.solves_per_s:>9.1f} {r.setup_s:>8.2f}"
            )
            print(f"{'':>18} settings: {r.settings}")


if __name__ == "__main__":
    # diffbody in float64 for the self-check; benchmarks/ik.py chooses for itself.
    jax.config.update("jax_enable_x64", True)
    main()
