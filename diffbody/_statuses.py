"""What every solve reports: `FitStatus` (the fits: clouds, motion capture, lifting, scaling)
and `ReachStatus` (reach), as integer codes that batches keep per row and files name."""

import enum


class FitStatus(enum.IntEnum):
    """How a solve ended."""

    CONVERGED = 0  # the solver's tolerances were met
    NOT_CONVERGED = 1  # the steps ran out: the last iterate, usable but not settled
    FAILED = 2  # a value became non-finite, or too little data: the start is returned

    def describe(self) -> str:
        """What the status means, in words."""
        return {
            "CONVERGED": "converged",
            "NOT_CONVERGED": "not converged: the last iterate after the step budget",
            "FAILED": "failed: the start is returned",
        }[self.name]


class ReachStatus(enum.IntEnum):
    """What a reach solve reports (`ReachResult.status`)."""

    SUCCESS = 0  # every valid target reached within the tolerance
    NOT_REACHED = 1  # a target missed although no bound rules it out: the closest reach found
    UNREACHABLE = 2  # a target lies beyond the reach of its chain: the closest reach
    INVALID_TARGET = 3  # a target is not finite: it took no part (the others were solved)
    CONSTRAINED = 4  # a target missed while every constraint holds: they stop the reach
    CONSTRAINT_VIOLATED = 5  # a constraint (contact, feet, balance) could not be kept

    def describe(self) -> str:
        """What the status means, in words."""
        return _DESCRIPTIONS[self]


_DESCRIPTIONS = {
    ReachStatus.SUCCESS: "reached",
    ReachStatus.NOT_REACHED: "not reached: no start found a posture within the tolerance",
    ReachStatus.UNREACHABLE: "not reached: target outside the reach envelope",
    ReachStatus.INVALID_TARGET: "invalid target (not finite): ignored",
    ReachStatus.CONSTRAINED: (
        "not reached: keeping balance, the feet planted or clear of contact stops the reach"
    ),
    ReachStatus.CONSTRAINT_VIOLATED: "a constraint (contact, feet, balance) is not kept",
}
