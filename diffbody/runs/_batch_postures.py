"""The postures of a streamed reach batch: one pose file per finished chunk while the run goes
on, joined into one pose file (`diffbody.pose/1`, kind "batch") at the end, a part at a
time: memory holds one part, however many rows the run had.

The join writes every per-row array of the parts to a raw file of its own beside the output,
then builds the .npz archive from them, each array an entry streamed into the zip (ZIP64,
deflated, as `numpy.savez_compressed` writes it), the document referring to its entries.
"""

import io
import json
import os
import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from .._spine import spine_angles
from ..files._pose_file import SCHEMA, read_document, save_pose, structure_hash
from . import _batch_file as bf
from ._streaming import fsync_file


def write_part(parts: str, index: int, body, result, xyz, effectors) -> None:
    """A chunk's postures as a pose file in the folder of parts, whole or not at all."""
    os.makedirs(parts, exist_ok=True)
    path = bf.part_path(parts, index)
    tmp = path[: -len(".npz")] + ".partial.npz"
    save_pose(
        tmp,
        body,
        result.pose,
        kind="batch",
        status=bf.status_names(result.status),
        residuals={"targets": result.residuals},
        overlays={"targets": {"names": list(effectors), "points": xyz}},
        extra={"reached": result.reached, "valid": result.valid, "steps": result.steps},
    )
    fsync_file(tmp)
    os.replace(tmp, path)


def _row_arrays(doc: dict, body, rest_spine: np.ndarray) -> dict[str, np.ndarray]:
    """A part's per-row arrays by their key in the document (a part whose rows the limbs
    alone reached names no spine target: the start's spine, as one solve of every row
    names it once the trunk moved in any)."""
    n = len(doc["status"])
    spine = doc.get("spine_target_deg")
    arrays = {
        "position": np.asarray(doc["position"], float),
        "spine_target_deg": np.repeat(rest_spine[None], n, 0)
        if spine is None
        else np.asarray(spine, float),
        "status": np.asarray(doc["status"], "U32"),
        "residuals/targets": np.asarray(doc["residuals"]["targets"], float),
        "overlays/targets/points": np.asarray(doc["overlays"]["targets"]["points"], float),
        "extra/reached": np.asarray(doc["extra"]["reached"], bool),
        "extra/valid": np.asarray(doc["extra"]["valid"], bool),
        "extra/steps": np.asarray(doc["extra"]["steps"], np.int64),
    }
    for name in body.segment_names:
        arrays[f"angles_deg/{name}"] = np.asarray(doc["angles_deg"][name], float)
    return arrays


def merge_postures(parts: str, n: int, poses: str, body, effectors) -> None:
    """The `n` parts' postures joined into one pose file `poses`, a part at a time, written
    whole or not at all."""
    rest_spine = np.zeros(3)  # a body without a spine: no part names a spine target
    if body.spine is not None:
        rest = spine_angles(body, body.spine, body.rest_pose()).sum(0)
        rest_spine = np.degrees(np.asarray(rest, float))
    folder = os.path.dirname(os.path.abspath(poses))
    with tempfile.TemporaryDirectory(dir=folder, prefix=".merging-") as tmp:
        shapes: dict[str, tuple[np.dtype, tuple[int, ...]]] = {}
        rows, any_spine = 0, False
        for index in range(n):
            doc = read_document(Path(bf.part_path(parts, index)))
            any_spine |= doc.get("spine_target_deg") is not None
            for key, a in _row_arrays(doc, body, rest_spine).items():
                shapes.setdefault(key, (a.dtype, a.shape[1:]))
                with open(os.path.join(tmp, _file(key)), "ab") as f:
                    f.write(np.ascontiguousarray(a, shapes[key][0]).tobytes())
            rows += len(doc["status"])
        if not any_spine:
            del shapes["spine_target_deg"]
        document = {
            "format": SCHEMA,
            "body": {"name": body.name, "structure": structure_hash(body)},
            "kind": "batch",
            "units": {"angles": "deg", "lengths": "m", "times": "s"},
            "position": {"npz": "position"},
            "angles_deg": {m: {"npz": f"angles_deg/{m}"} for m in body.segment_names},
            "spine_target_deg": {"npz": "spine_target_deg"} if any_spine else None,
            "times": None,
            "status": {"npz": "status"},
            "residuals": {"targets": {"npz": "residuals/targets"}},
            "scale": {},
            "overlays": {
                "targets": {"names": list(effectors), "points": {"npz": "overlays/targets/points"}}
            },
            "extra": {k: {"npz": f"extra/{k}"} for k in ("reached", "valid", "steps")},
        }
        partial = poses[: -len(".npz")] + ".partial.npz"
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
            zf.writestr("document.npy", _npy(np.asarray(json.dumps(document))))
            for key, (dtype, tail) in shapes.items():
                with zf.open(f"{key}.npy", "w", force_zip64=True) as entry:
                    header = {"descr": np.lib.format.dtype_to_descr(dtype), "shape": (rows, *tail)}
                    np.lib.format.write_array_header_2_0(entry, header | {"fortran_order": False})
                    with open(os.path.join(tmp, _file(key)), "rb") as f:
                        shutil.copyfileobj(f, entry, 1 << 20)
    fsync_file(partial)
    os.replace(partial, poses)


def _file(key: str) -> str:
    return key.replace("/", "~") + ".raw"


def _npy(a: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, a, allow_pickle=False)
    return buffer.getvalue()
