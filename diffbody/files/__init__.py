"""File formats: the body and spine files (JSON, their schema in data/SCHEMA.md), the checks
every reader shares, saving a body back to a file, and OpenSim's motion files (.mot)."""

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
from ._saving import (
    save_body as save_body,
)
from ._spine_file import (
    load_spine as load_spine,
)
