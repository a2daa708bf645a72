"""Motion capture: a body scaled and its markers registered on a static trial, every frame of
a trial fitted to its markers, folders of trials, joint-angle plots. The marker files and marker
sets are read by `diffbody.files`."""

from ._grades import Grade as Grade
from ._grades import grade_motion as grade_motion
from ._grades import grade_static as grade_static
from ._markerset import MarkerWarning as MarkerWarning
from ._markerset import match_markers as match_markers
from ._markerset import scale_offsets as scale_offsets
from ._markerset import world_markers as world_markers
from ._model_frames import model_frames as model_frames
from ._motion_fit import fit_motion as fit_motion
from ._motion_limits import MOTION_RANGES as MOTION_RANGES
from ._motion_limits import motion_limits as motion_limits
from ._motion_plots import draw_motion as draw_motion
from ._motion_result import MotionFit as MotionFit
from ._static_fit import StaticFit as StaticFit
from ._static_fit import scale_and_register as scale_and_register
from ._trials import TrialsSummary as TrialsSummary
from ._trials import fit_trials as fit_trials
