"""Progress of long batches (reach, scaling, fits, frames): tqdm's bar, which draws a widget
in a notebook and a line in a terminal."""

import sys
import warnings


def _tqdm():
    """tqdm.auto's class: the notebook widget under Jupyter (where ipywidgets is installed),
    else the terminal bar; without ipywidgets tqdm warns once and uses the text bar, which
    a notebook shows as well."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from tqdm.auto import tqdm
    return tqdm


class Progress:
    """A progress bar over `total` items counted in `unit`s ("solve", "frame", ...), shown
    when `enabled`. Where stderr is not a terminal (a log file, CI) it redraws at most
    every 10 s instead of continuously."""

    def __init__(self, total: int, enabled: bool, label: str = "reach", unit: str = "row"):
        self.bar = None
        if enabled:
            terminal = hasattr(sys.stderr, "isatty") and sys.stderr.isatty()
            self.bar = _tqdm()(
                total=total,
                desc=label,
                unit=unit,
                file=sys.stderr,
                mininterval=0.1 if terminal else 10.0,
                dynamic_ncols=terminal,
            )

    def update(self, done: int) -> None:
        """`done` items of `total` are finished; the bar closes when all are."""
        if self.bar is None:
            return
        self.bar.update(done - self.bar.n)
        if done >= self.bar.total:
            self.bar.close()
