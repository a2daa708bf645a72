"""A folder that keeps a batch's finished chunks (`map_chunks(..., store=)`), so that a long
`scale_population` or `fit_spheres_batch` loses nothing to an interrupt and goes on where it
stopped (`out=`, `resume=True`).

    OUT/run.json          what produced the run (format, function, input hash, settings)
    OUT/part-00000.npz    each finished chunk's outputs, their leaves in order (arr_0, ...)

A part is written whole (a temporary name, fsync, rename) before the chunk counts as done.
A resumed run reads the parts there are and solves the rest; it is refused, naming what
changed, when the input or a setting differs from the run that began the folder.
"""

import hashlib
import json
import os
import re
from dataclasses import dataclass

import numpy as np

from ._header import BODY_KEYS, header_changes
from ._streaming import fsync_file, replace_atomically

FORMAT = "diffbody.chunks/1"


@dataclass
class ChunkStore:
    """The folder `path` of a run's kept chunks."""

    path: str

    @classmethod
    def open(cls, path, fields: dict[str, str], chunk: int, resume: bool) -> "ChunkStore":
        """Begin the folder (emptied of an earlier run's parts), or with `resume` go on with
        it after checking that it was begun by the same run."""
        path = os.fspath(path)
        fields = {"format": FORMAT, **fields, "chunk-size": str(chunk)}
        record = os.path.join(path, "run.json")
        if resume and os.path.exists(record):
            with open(record, encoding="utf-8") as f:
                old = json.load(f)
            settings = {key: key for key in fields if key not in BODY_KEYS}
            changed = header_changes(old, fields, {}, settings)
            if changed:
                raise ValueError(
                    f"resume=True {path}: {'; '.join(changed)}; call again as it was begun, "
                    "or without resume to start over"
                )
            return cls(path)
        os.makedirs(path, exist_ok=True)
        for name in os.listdir(path):
            if re.fullmatch(r"part-\d+(\.partial)?\.npz", name):
                os.remove(os.path.join(path, name))
        replace_atomically(record, json.dumps(fields, indent=1) + "\n")
        return cls(path)

    def _part(self, index: int) -> str:
        return os.path.join(self.path, f"part-{index:05d}.npz")

    def load(self, index: int) -> list[np.ndarray] | None:
        """Chunk `index`'s outputs (leaves in order), or None when it is not done."""
        if not os.path.exists(self._part(index)):
            return None
        with np.load(self._part(index), allow_pickle=False) as archive:
            return [archive[f"arr_{i}"] for i in range(len(archive.files))]

    def save(self, index: int, leaves: list[np.ndarray]) -> None:
        """Keep chunk `index`'s outputs, whole or not at all."""
        tmp = self._part(index)[: -len(".npz")] + ".partial.npz"
        np.savez(tmp, *leaves)
        fsync_file(tmp)
        os.replace(tmp, self._part(index))


def input_hash(*arrays) -> str:
    """16 hex digits naming input arrays exactly (dtype, shape and bytes; None too)."""
    digest = hashlib.sha256()
    for a in arrays:
        if a is None:
            digest.update(b"none")
            continue
        a = np.asarray(a)
        digest.update(f"{a.dtype}{a.shape}".encode())
        digest.update(np.ascontiguousarray(a).tobytes())
    return digest.hexdigest()[:16]


def float_name() -> str:
    """JAX's float type now (JAX_ENABLE_X64 changes the results)."""
    import jax.numpy as jnp

    return np.dtype(jnp.result_type(float)).name
