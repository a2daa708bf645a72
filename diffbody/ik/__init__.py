"""Inverse kinematics: targets, the solver's unknowns and residuals, starts, the post-solve
projection onto the standard orientation, and the single and batch reach solves."""

from ._batch_run import (
    BatchRun as BatchRun,
)
from ._reach import (
    ReachResult as ReachResult,
)
from ._reach import (
    ReachStatus as ReachStatus,
)
from ._reach import (
    solve_reach as solve_reach,
)
from ._reach_batch import (
    solve_reach_batch as solve_reach_batch,
)
from ._targets import (
    Target as Target,
)
