"""Fitting a body to measurements: sphere clouds, and motion capture (marker files, marker
sets, scaling and registration on a static trial, every frame of a trial, a folder of trials,
OpenSim's set-up files)."""

from ._clouds import (
    sample_pose as sample_pose,
)
from ._clouds import (
    synthetic_cloud as synthetic_cloud,
)
from ._marker_trial import (
    LAB_AXES as LAB_AXES,
)
from ._marker_trial import (
    MarkerFileError as MarkerFileError,
)
from ._marker_trial import (
    MarkerTrial as MarkerTrial,
)
from ._markers import (
    c3d_screen_axes as c3d_screen_axes,
)
from ._markers import (
    read_c3d as read_c3d,
)
from ._markers import (
    read_markers as read_markers,
)
from ._markerset import (
    MarkerSet as MarkerSet,
)
from ._markerset import (
    MarkerWarning as MarkerWarning,
)
from ._markerset import (
    load_markerset as load_markerset,
)
from ._markerset import (
    match_markers as match_markers,
)
from ._markerset import (
    scale_offsets as scale_offsets,
)
from ._markerset import (
    world_markers as world_markers,
)
from ._motion_fit import (
    MotionFit as MotionFit,
)
from ._motion_fit import (
    fit_motion as fit_motion,
)
from ._motion_limits import (
    MOTION_RANGES as MOTION_RANGES,
)
from ._motion_limits import (
    motion_limits as motion_limits,
)
from ._motion_plots import (
    draw_motion as draw_motion,
)
from ._opensim_files import (
    load_opensim_markerset as load_opensim_markerset,
)
from ._opensim_files import (
    read_ik_tasks as read_ik_tasks,
)
from ._sphere_fit import (
    FitStatus as FitStatus,
)
from ._sphere_fit import (
    SphereFit as SphereFit,
)
from ._sphere_fit import (
    fit_spheres as fit_spheres,
)
from ._sphere_fit import (
    fit_spheres_batch as fit_spheres_batch,
)
from ._static_fit import (
    StaticFit as StaticFit,
)
from ._static_fit import (
    scale_and_register as scale_and_register,
)
from ._trc import (
    read_trc as read_trc,
)
from ._trc import (
    write_trc as write_trc,
)
from ._trials import (
    TrialsSummary as TrialsSummary,
)
from ._trials import (
    fit_trials as fit_trials,
)
