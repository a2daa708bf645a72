"""How a motion-capture fit grades against OpenSim's best practices, per marker class and
per frame, naming what breaks them (OpenSim documentation, "Simulation with OpenSim - Best
Practices"). Scaling: "maximum marker errors for bony landmarks should be less than 2 cm",
"RMS error should typically be less than 1 cm". Inverse kinematics: "maximum marker error
should generally be less than 2-4 cm, and RMS under 2 cm" (the upper end, 4 cm, is the
limit here). Bony landmarks are the marker set's "anatomical" markers."""

from dataclasses import dataclass

import numpy as np

SCALE_RMS, SCALE_MAX = 0.01, 0.02  # m: the static fit's bony landmarks
IK_RMS, IK_MAX = 0.02, 0.04  # m: a frame of the motion
KINDS = ("anatomical", "tracking")


@dataclass(frozen=True)
class Grade:
    """One figure against its threshold: `what` was measured, its `value` and `limit` in
    `unit` ("m", or "share" of frames), whether it is `met`, and what `breaks` it: (marker,
    its error in m, or the share of frames it is over the limit in), worst first."""

    what: str
    value: float
    limit: float
    met: bool
    breaks: tuple[tuple[str, float], ...] = ()
    unit: str = "m"

    def line(self) -> str:
        """The grade in one line of the command's report."""
        if self.unit == "m":
            shown = f"{100 * self.value:.2f} cm (< {100 * self.limit:.0f} cm)"
            worst = ", ".join(f"{n} {100 * v:.1f} cm" for n, v in self.breaks[:3])
        else:
            shown = f"{100 * self.value:.0f} % (goal {100 * self.limit:.0f} %)"
            worst = ", ".join(f"{n} in {100 * v:.0f} % of frames" for n, v in self.breaks[:3])
        verdict = "met" if self.met else "not met"
        return f"{self.what}: {shown}, {verdict}" + (f"; worst: {worst}" if worst else "")


def grade_static(static_fit) -> list[Grade]:
    """The static fit's bony landmarks (anatomical markers): RMS < 1 cm, each < 2 cm."""
    kinds = np.asarray(static_fit.markerset.kinds)
    errors = np.asarray(static_fit.errors, float)
    bony = kinds == "anatomical"
    if not bony.any():
        return []
    names = np.asarray(static_fit.markerset.names)[bony]
    e = errors[bony]
    over = sorted(
        ((str(n), float(v)) for n, v in zip(names, e) if v > SCALE_MAX), key=lambda t: -t[1]
    )
    rms = float(np.sqrt(np.mean(e**2)))
    return [
        Grade(f"scaling, {bony.sum()} bony landmarks, RMS", rms, SCALE_RMS, rms < SCALE_RMS),
        Grade(
            f"scaling, {bony.sum()} bony landmarks, largest", float(e.max()), SCALE_MAX, not over,
            tuple(over),
        ),
    ]  # fmt: skip


def grade_motion(motion) -> list[Grade]:
    """Every frame of the motion fit: per marker class the RMS over its frames (< 2 cm); the
    share of frames whose RMS is under 2 cm and whose every marker is under 4 cm (goal: all),
    with the markers that most often pass 4 cm."""
    errors = np.asarray(motion.errors, float)
    out = []
    for kind in KINDS:
        cols = [k for k, c in enumerate(motion.kinds) if c == kind]
        if cols:
            e = errors[:, cols]
            rms = float(np.sqrt(np.nanmean(e**2)))
            out.append(Grade(f"motion, {len(cols)} {kind} markers, RMS", rms, IK_RMS, rms < IK_RMS))
    rms, worst = np.asarray(motion.rms, float), np.asarray(motion.max, float)
    good = (rms < IK_RMS) & (worst < IK_MAX)
    seen = np.isfinite(errors).sum(axis=0)
    share = np.sum(errors > IK_MAX, axis=0) / np.maximum(seen, 1)  # of the frames that see it
    breaks = sorted(
        ((n, float(s)) for n, s in zip(motion.names, share) if s > 0), key=lambda t: -t[1]
    )
    what = (
        f"motion, frames with RMS < {100 * IK_RMS:.0f} cm and every marker < {100 * IK_MAX:.0f} cm"
    )
    out.append(Grade(what, float(good.mean()), 1.0, bool(good.all()), tuple(breaks), "share"))
    return out


def readings_report(body, measured: dict) -> str:
    """Tape or caliper readings (`scale_and_register`'s `measured`, m) against what the
    scaled `body` measures: a line each, read, fitted and their difference (mm)."""
    from ..anthropometry._measurements import measurements

    fitted = measurements(body, tuple(measured))
    rows = [
        f"  {n}: read {v:.3f} m, fitted {fitted[n]:.3f} m ({1000 * (fitted[n] - v):+.1f} mm)"
        for n, v in measured.items()
    ]
    return "\n".join(["readings against the scaled body:", *rows])


def registration_report(static_fit) -> str | None:
    """The motion's frames a registration fitted as well (`scale_and_register(motion=)`),
    and their markers' RMS, in a line; None when it registered on the static trial alone."""
    if static_fit.motion_errors is None:
        return None
    e = np.asarray(static_fit.motion_errors)
    trials = len({t for t, _ in static_fit.motion_frames})
    return (
        f"  registered on {len(static_fit.motion_frames)} frames of {trials} motion trial(s) as "
        f"well (--motion-frames): their marker RMS {100 * np.sqrt(np.nanmean(e**2)):.2f} cm"
    )
