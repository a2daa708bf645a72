"""Every file format diffbody reads or writes: the body and spine files (JSON, their schema in
data/SCHEMA.md), the checks every reader shares, saving a body back to a file, the pose file of
every result (`save_pose`, `load_pose`), targets, marker files (TRC, C3D), marker sets (ours and
OpenSim's XML), OpenSim's IK task sets and motion files (.mot)."""

from ._body_file import (
    load_body as load_body,
)
from ._data_files import (
    BodyFileError as BodyFileError,
)
from ._data_files import (
    data_file as data_file,
)
from ._marker_files import c3d_screen_axes as c3d_screen_axes
from ._marker_files import read_c3d as read_c3d
from ._marker_files import read_markers as read_markers
from ._marker_trial import LAB_AXES as LAB_AXES
from ._marker_trial import MarkerFileError as MarkerFileError
from ._marker_trial import MarkerTrial as MarkerTrial
from ._markerset_file import MarkerSet as MarkerSet
from ._markerset_file import load_markerset as load_markerset
from ._motion_files import (
    MotionFileError as MotionFileError,
)
from ._motion_files import (
    read_mot as read_mot,
)
from ._motion_files import (
    write_mot as write_mot,
)
from ._opensim_files import load_opensim_markerset as load_opensim_markerset
from ._opensim_files import read_ik_tasks as read_ik_tasks
from ._opensim_files import read_model_markers as read_model_markers
from ._pose_file import (
    PoseFileError as PoseFileError,
)
from ._pose_file import (
    PoseRecord as PoseRecord,
)
from ._pose_file import (
    load_pose as load_pose,
)
from ._pose_file import (
    save_pose as save_pose,
)
from ._pose_file import (
    structure_hash as structure_hash,
)
from ._saving import (
    save_body as save_body,
)
from ._spine_file import (
    load_spine as load_spine,
)
from ._trc import read_trc as read_trc
from ._trc import write_trc as write_trc
