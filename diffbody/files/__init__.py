"""File formats: the body and spine files (JSON, their schema in data/SCHEMA.md), the checks
every reader shares, saving a body back to a file, the pose file of every result
(`save_pose`, `load_pose`) and OpenSim's motion files (.mot)."""

from ._body_file import (
    load_body as load_body,
)
from ._data_files import (
    BodyFileError as BodyFileError,
)
from ._data_files import (
    data_file as data_file,
)
from ._motion_files import (
    MotionFileError as MotionFileError,
)
from ._motion_files import (
    read_mot as read_mot,
)
from ._motion_files import (
    write_mot as write_mot,
)
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
