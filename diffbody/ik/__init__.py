"""Inverse kinematics: starts, phases, rounds and attempts on `problem`'s least-squares
problem, the post-solve projection onto the standard orientation, and the single and batch
reach solves (in memory, or written to a file as they go)."""

from .._statuses import ReachStatus as ReachStatus
from ..problem._targets import Target as Target
from ..runs._batch_run import BatchRun as BatchRun
from ._reach import ReachResult as ReachResult
from ._reach import solve_reach as solve_reach
from ._reach_batch import solve_reach_batch as solve_reach_batch
from ._reach_run import run_reach_batch as run_reach_batch
