"""Batch reach: equals a loop of solve_reach, chunking and sharding change nothing, NaN
rows are flagged. One compiled batch function (chunks of 2) is shared by every test."""

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compiles import counted_compiles
from hypothesis import given, settings
from hypothesis import strategies as st

import diffbody as db
from diffbody.ik._reach import reach_status
from diffbody.ik._reach_batch import solve_reach_batch

CHUNK = 2  # every batch here compiles the same function once
# The arm alone from one start: the batching is under test, not the solver (compiles fast).
ARM = ("left_upper_arm", "left_forearm", "left_hand")
SOLVER = dict(segments=ARM, starts=1)
ROWS = np.array([[0.3, 0.2, 1.0], [0.15, 0.3, 0.85], [0.35, 0.1, 1.15], [0.2, 0.45, 0.9]])


@pytest.fixture(scope="module")
def batch(male50):
    """Four rows in two chunks."""
    return solve_reach_batch(
        male50, ["left_hand.palm"], ROWS, chunk_size=CHUNK, progress=False, **SOLVER
    )


def test_batch_equals_a_loop_of_solve_reach(male50, batch):
    """The same solve, vmapped: equal to rounding (1.3e-15 rad measured; vmapped, XLA turns
    `unsquash`'s division by the chunk's shared bounds into a product with their reciprocal).
    The closed-form start keeps the arm off its socket's pole, where it hangs in the standard
    position: its table frame is not differentiable there and the last bits pick the Jacobian
    (rows started there, each from its own copy of the pose, came 1.7e-3 rad apart)."""
    assert batch.residuals.shape == (4, 1) and batch.pose.angles.shape[0] == 4
    for i, xyz in enumerate(ROWS):
        one = db.solve_reach(male50, [db.Target.position("left_hand.palm", xyz)], **SOLVER)
        np.testing.assert_allclose(batch.residuals[i], np.asarray(one.residuals), atol=1e-12)
        assert bool(batch.reached[i, 0]) == bool(one.reached[0])
        assert int(batch.steps[i]) == int(one.steps)
        np.testing.assert_allclose(batch.pose.angles[i], np.asarray(one.pose.angles), atol=1e-9)
    assert batch.reached.all()


def test_a_row_is_the_same_whatever_shares_its_chunk(male50, batch):
    """A row solved beside a copy of itself, and beside a row out of reach whose lane goes on
    for three rounds after this one stopped, gives the same answer to the bit as beside
    another row: every lane stops on its own and nothing crosses lanes."""
    far = ROWS[0] - [0.0, 0.0, 1.0]  # at the feet: out of the arm's reach
    out = solve_reach_batch(
        male50,
        "left_hand.palm",
        np.stack([ROWS[0], far, ROWS[0], ROWS[0]]),
        chunk_size=CHUNK,
        progress=False,
        **SOLVER,
    )
    assert not out.reached[1, 0] and out.steps[1] == 30 and batch.steps[0] < 10
    for i in (0, 2, 3):
        np.testing.assert_array_equal(out.pose.angles[i], batch.pose.angles[0])
        np.testing.assert_array_equal(out.residuals[i], batch.residuals[0])
        assert out.steps[i] == batch.steps[0]


def test_chunks_equal_one_chunk(male50, batch):
    """Three rows in one chunk (of four: the row counts' bucket) as in chunks of two."""
    one_chunk = solve_reach_batch(male50, "left_hand.palm", ROWS[1:], progress=False, **SOLVER)
    np.testing.assert_allclose(one_chunk.residuals, batch.residuals[1:], atol=1e-12)
    np.testing.assert_allclose(one_chunk.pose.angles, batch.pose.angles[1:], atol=1e-12)
    np.testing.assert_array_equal(one_chunk.reached, batch.reached[1:])


def test_row_counts_within_a_bucket_share_one_program(male50, batch):
    """Three rows and four run one program (a chunk of four rows, the last repeated), and
    computing the rows' verdicts compiles nothing per row count (they are NumPy)."""
    solve_reach_batch(male50, "left_hand.palm", ROWS[1:], progress=False, **SOLVER)
    with counted_compiles() as seen:
        four = solve_reach_batch(male50, "left_hand.palm", ROWS[::-1], progress=False, **SOLVER)
        three = solve_reach_batch(male50, "left_hand.palm", ROWS[:3], progress=False, **SOLVER)
    assert seen == []
    np.testing.assert_allclose(four.residuals[::-1], batch.residuals, atol=1e-12)
    np.testing.assert_array_equal(three.status, batch.status[:3])


def test_another_limb_compiles_nothing(male50, batch):
    """Every limb chain of up to four segments runs one program (`_tree.limb_layout`, its
    segments data): after the left arm's rows, the right arm's and the left leg's (the
    ankle, a few centimetres forward and up) compile nothing new, and reach."""
    right = ROWS * [1.0, -1.0, 1.0]
    right_arm = [name.replace("left", "right") for name in ARM]
    ankle = np.asarray(db.forward(male50, male50.rest_pose()).joint_positions)[
        male50.joint_names.index("left_ankle")
    ]
    feet = ankle + np.asarray([[0.15, 0.0, 0.1], [0.1, 0.05, 0.05]])
    with counted_compiles() as seen:
        arm = solve_reach_batch(
            male50, "right_hand.palm", right, chunk_size=CHUNK, progress=False,
            segments=right_arm, starts=1,
        )  # fmt: skip
        leg = solve_reach_batch(
            male50, "left_ankle", feet, chunk_size=CHUNK, progress=False, starts=1, standing=False
        )
    assert seen == []
    assert arm.reached.all() and leg.reached.all()
    # The right arm mirrors the left: the same distances, to rounding.
    np.testing.assert_allclose(arm.residuals, batch.residuals, atol=1e-6)


def test_several_limbs_run_on_their_limb_chains(male50, batch):
    """Rows with a target on each hand: the limbs' phase runs each arm's columns as a batch
    on its limb chain (`_limb_groups`), compiling nothing after the one-arm batches (a
    regression: such batches compiled their phase's own layout), and each row is what
    `solve_reach` gives it, to rounding."""
    right = ROWS * [1.0, -1.0, 1.0]
    arms = list(ARM) + [name.replace("left", "right") for name in ARM]
    effectors = ["left_hand.palm", "right_hand.palm"]
    with counted_compiles() as seen:
        out = solve_reach_batch(
            male50, effectors, np.stack([ROWS, right], axis=1), chunk_size=CHUNK,
            progress=False, segments=arms, starts=1,
        )  # fmt: skip
    assert seen == []
    assert out.residuals.shape == (4, 2) and out.reached.all(), out.residuals
    for i in range(len(ROWS)):
        targets = [db.Target.position(e, xyz) for e, xyz in zip(effectors, (ROWS[i], right[i]))]
        one = db.solve_reach(male50, targets, segments=arms, starts=1)
        np.testing.assert_allclose(out.residuals[i], np.asarray(one.residuals), atol=1e-12)
        np.testing.assert_allclose(out.pose.angles[i], np.asarray(one.pose.angles), atol=1e-9)
        assert int(out.steps[i]) == int(one.steps)


def test_rows_the_limbs_miss_go_on_to_the_trunk(male50, batch):
    """The limbs' phase on a limb chain, then the trunk's on its own layout for the row the
    arm cannot reach: both phases' attempts merge (regression: the limb chain's pad axis
    row once broke the merge), the near row as the arm alone solves it, the far one
    reached by bending the spine."""
    far = ROWS[0] + [0.3, 0.0, -0.2]
    out = solve_reach_batch(
        male50, "left_hand.palm", np.stack([ROWS[0], far]), chunk_size=CHUNK,
        progress=False, starts=1, standing=False,
    )  # fmt: skip
    assert out.residuals.shape == (2, 1) and out.reached.all(), out.residuals
    near, trunk = (np.asarray(out.pose.spine_target[i]) for i in (0, 1))
    rest = np.asarray(db.spine_angles(male50, male50.spine, male50.rest_pose()).sum(0))
    np.testing.assert_allclose(near, rest, atol=1e-9)  # the arm alone
    assert np.abs(trunk - rest).max() > np.deg2rad(5.0)  # the spine bent


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**16 - 1), st.integers(0, 3))
def test_the_host_verdicts_are_the_compiled_ones(bits, n_kinds):
    """`reach_status` in NumPy (the batch's rows) equals it in JAX (a single solve's,
    compiled), for every pattern of verdicts of 3 rows of 2 targets and up to 3 constraint
    kinds."""
    flags = (bits >> np.arange(16)) & 1 == 1
    reached, valid, beyond = (flags[i : i + 6].reshape(3, 2) for i in (0, 5, 10))
    kept = np.resize(flags[::-1], (3, n_kinds))
    host = reach_status(reached, valid, beyond, kept)
    compiled = _status_jit(*(jnp.asarray(a) for a in (reached, valid, beyond, kept)))
    np.testing.assert_array_equal(host, np.asarray(compiled))


_status_jit = jax.jit(jax.vmap(reach_status))


def test_a_nan_row_is_flagged_and_the_others_solved(male50, batch, capsys):
    rows = np.stack([ROWS[0], [np.nan, 0.2, 1.0], ROWS[1]])  # 3 rows: the last chunk is padded
    out = solve_reach_batch(male50, ["left_hand.palm"], rows, chunk_size=CHUNK, **SOLVER)
    err = capsys.readouterr().err  # the progress bar
    assert "reach: 100%" in err and "3/3 [" in err and "solve" in err
    np.testing.assert_array_equal(out.valid[:, 0], [True, False, True])
    np.testing.assert_array_equal(out.reached[:, 0], [True, False, True])
    assert all(np.all(np.isfinite(a)) for a in (out.residuals, out.pose.angles))
    np.testing.assert_allclose(out.residuals[[0, 2]], batch.residuals[:2], atol=1e-12)


def test_bad_input_is_rejected(male50):
    with pytest.raises(KeyError, match="unknown effector"):
        solve_reach_batch(male50, ["left_elbowz"], ROWS, progress=False)
    with pytest.raises(ValueError, match=r"shape \(n, 2, 3\)"):
        solve_reach_batch(male50, ["left_hand.palm", "left_wrist"], ROWS, progress=False)


SHARDED = textwrap.dedent(
    """
    import json, jax, numpy as np, diffbody as db
    from diffbody.ik._reach_batch import solve_reach_batch
    rows = np.asarray(json.loads(input()))
    arm = ("left_upper_arm", "left_forearm", "left_hand")
    out = solve_reach_batch(db.load_body(variant="male50"), ["left_hand.palm"], rows,
                            chunk_size=2, progress=False, segments=arm, starts=1)
    print(json.dumps({"devices": len(jax.devices()), "residuals": out.residuals.tolist(),
                      "angles": out.pose.angles.tolist(), "reached": out.reached.tolist()}))
    """
)


@pytest.mark.slow
def test_sharded_equals_unsharded(batch):
    """Two CPU devices in a subprocess shard each chunk of 2 rows, one row per device; the
    unsharded reference is this process's single-device `batch` (saves a second compile).
    The subprocess compiles with this process's XLA flags: one row per device rounds like
    `solve_reach`, the batch of two as in the first test (measured within 2.2e-15 rad)."""
    flags = (os.environ.get("XLA_FLAGS"), "--xla_force_host_platform_device_count=2")
    env = dict(
        os.environ,
        XLA_FLAGS=" ".join(filter(None, flags)),
        JAX_ENABLE_X64="1",
        JAX_PLATFORMS="cpu",
    )
    run = subprocess.run(
        [sys.executable, "-c", SHARDED],
        input=json.dumps(ROWS.tolist()),
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["devices"] == 2
    assert np.max(np.abs(np.asarray(got["residuals"]) - batch.residuals)) < 1e-12
    assert np.max(np.abs(np.asarray(got["angles"]) - batch.pose.angles)) < 1e-9
    np.testing.assert_array_equal(got["reached"], batch.reached)
