"""Sphere-cloud files: a NumPy .npz archive with ``centers`` (m, 3) and ``radii`` (m,) in
metres, and optionally ``correspondences`` (m,), the model sphere each measured one is."""

import numpy as np


def read_cloud(path):
    """centers (m, 3), radii (m,) and correspondences (m,) or None from an .npz file; errors
    name the file and the array a cloud needs."""
    try:
        data = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as e:
        if isinstance(e, (FileNotFoundError, IsADirectoryError, PermissionError)):
            raise
        raise ValueError(
            f"{path}: not a NumPy .npz file ({e}); write one with "
            "numpy.savez(path, centers=(m, 3) array in m, radii=(m,) array in m)"
        ) from None
    if not hasattr(data, "files"):
        raise ValueError(f"{path}: a single array, not an .npz archive of named arrays")
    for key in ("centers", "radii"):
        if key not in data.files:
            raise ValueError(
                f"{path}: no array {key!r} (found {sorted(data.files)}); give centers=(m, 3) "
                "and radii=(m,) in m, and optionally correspondences=(m,) model sphere indices"
            )
    match = data["correspondences"] if "correspondences" in data.files else None
    return data["centers"], data["radii"], match
