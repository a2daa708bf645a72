"""A one-line progress bar for long batches (reach, scaling, fits, frames)."""

import math
import sys
import time


def _duration(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    s = int(round(s))
    h, r = divmod(s, 3600)
    m, s = divmod(r, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s" if m else f"{s}s"


class Progress:
    """A one-line progress bar on stderr: solves done / total, rate, ETA."""

    def __init__(self, total: int, enabled: bool, label: str = "reach", width: int = 30):
        self.total, self.enabled, self.label, self.width = total, enabled, label, width
        self.t0 = time.perf_counter()

    def update(self, done: int) -> None:
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.t0
        rate = done / elapsed if elapsed > 0 else float("nan")
        eta = (self.total - done) / rate if rate > 0 else float("inf")
        fill = int(self.width * done / max(self.total, 1))
        bar = "#" * fill + "." * (self.width - fill)
        end = "\n" if done >= self.total else ""
        sys.stderr.write(
            f"\r{self.label} [{bar}] {done}/{self.total} solves, {rate:.3g}/s, "
            f"ETA {_duration(eta)}   {end}"
        )
        sys.stderr.flush()
