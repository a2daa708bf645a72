"""The pose file (`diffbody.pose/1`): one schema for every result that holds postures, a
single pose, a time sequence (motion capture, image sequences) or a batch (many reach
targets), with the body it belongs to and, optionally, what the solve measured.

Two containers of the same document (data/SCHEMA.md, "Pose files"):

- ``*.json``: the document as JSON, every array as nested lists. Readable, diffable; for a
  pose or a sequence of a few hundred frames.
- ``*.npz``: NumPy's archive. Entry ``document`` holds the JSON text with each array larger
  than `INLINE` numbers replaced by ``{"npz": key}``, the array stored under that key. For
  batches of thousands of postures.

A pose belongs to a body *structure* (segment names, tree, joints, limit kinds), not to its
dimensions: a pose of male50 loads onto female50 or a scaled body, never onto a body with
another tree. `load_pose(path, body)` refuses such a file, naming both.
"""

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._body import Body, Pose
from ._data_files import read_json

SCHEMA = "diffbody.pose/1"
KINDS = ("pose", "sequence", "batch")
INLINE = 4096  # numbers: larger arrays of an .npz document live in their own entries


class PoseFileError(ValueError):
    """A pose file that cannot be read onto a body; the message names the file, the field
    and the fix."""


def structure_hash(body: Body) -> str:
    """16 hex digits naming the body's structure: what a pose's rows mean (segment and joint
    names, the tree, the limit kinds, the root joint and the spine's joints), not its
    dimensions."""
    spine = body.spine.joint_names if body.spine is not None else ()
    text = json.dumps(
        [
            body.segment_names,
            body.joint_names,
            body.parent,
            body.proximal_joint,
            body.distal_joint,
            body.standard_kind,
            body.limit_kind,
            body.root_joint,  # what Pose.position places (Body.with_root)
            spine,
        ]
    )
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class PoseRecord:
    """What a pose file holds, read back by `load_pose`.

    `pose` is a `Pose` with a leading axis (n_frames,) unless `kind` is "pose". `times` (s,
    a sequence's frame times) or None. `status`: one name ("converged") or one per frame.
    `residuals`: named arrays (m or rad) whose leading axis is the frame. `scale`: the body
    scaling a fit found (named arrays or numbers). `overlays`: what to draw over the body,
    any of ``targets`` {names, points (k, 3) m}, ``markers`` {names, positions (n_frames,
    m, 3) m}, ``cloud`` {centers (m, 3), radii (m,), inliers (m,)}. `extra`: the
    workflow's own fields (effector, steps, ...), as saved.
    """

    path: str
    body_name: str
    structure: str
    kind: str
    pose: Pose
    times: np.ndarray | None = None
    status: str | tuple[str, ...] | None = None
    residuals: dict[str, np.ndarray] = field(default_factory=dict)
    scale: dict[str, Any] = field(default_factory=dict)
    overlays: dict[str, dict[str, Any]] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        """1 for a single pose, else the length of the leading axis."""
        return 1 if self.kind == "pose" else int(self.pose.angles.shape[0])

    def frame(self, i: int) -> Pose:
        """The i-th posture (the pose itself for kind "pose")."""
        if self.kind == "pose":
            return self.pose
        spine = None if self.pose.spine_target is None else self.pose.spine_target[i]
        return Pose(self.pose.position[i], self.pose.angles[i], spine)


def _plain(value: Any) -> Any:
    """JSON-ready: arrays to nested lists, NumPy scalars to numbers, recursively."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "__array__") or isinstance(value, np.generic):
        return np.asarray(value).tolist()
    return value


def save_pose(
    path: str | Path,
    body: Body,
    pose: Pose,
    *,
    kind: str | None = None,
    times: Any = None,
    status: Any = None,
    residuals: dict[str, Any] | None = None,
    scale: dict[str, Any] | None = None,
    overlays: dict[str, dict[str, Any]] | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write a pose, a sequence or a batch of poses of `body` to a pose file.

    Args:
        path: ``*.json`` or ``*.npz`` (the container follows the suffix).
        body: the body the poses belong to (its name and structure hash are saved).
        pose: a `Pose`; angles (n_seg, 3) for one pose, (n, n_seg, 3) with position (n, 3)
            for a sequence or a batch.
        kind: "pose", "sequence" (frames in time order) or "batch" (independent solves);
            default "pose" for one pose, "sequence" when `times` is given, else "batch".
        times: (n,) s, a sequence's frame times.
        status: the solve's verdict, one name or one per frame (enum members are saved by
            their lower-case names).
        residuals, scale, overlays, extra: see `PoseRecord`.

    Returns:
        the path written.
    """
    path = Path(path)
    angles = np.asarray(pose.angles, dtype=float)
    position = np.asarray(pose.position, dtype=float)
    batched = angles.ndim == 3
    if angles.shape[-2:] != (body.n_segments, 3) or angles.ndim not in (2, 3):
        raise ValueError(
            f"save_pose: angles of shape {angles.shape}; expected ({body.n_segments}, 3) "
            f"or (n, {body.n_segments}, 3) for body {body.name!r}"
        )
    if position.shape != angles.shape[:-2] + (3,):
        raise ValueError(f"save_pose: position of shape {position.shape} for angles {angles.shape}")
    if kind is None:
        kind = "pose" if not batched else ("sequence" if times is not None else "batch")
    if kind not in KINDS or (kind == "pose") == batched:
        raise ValueError(
            f"save_pose: kind {kind!r} for angles of shape {angles.shape}; one of {KINDS}, "
            "'pose' exactly when there is no leading axis"
        )
    if path.suffix not in (".json", ".npz"):
        raise ValueError(f"save_pose: {path}: the file name must end in .json or .npz")
    degrees = np.degrees(angles)
    spine = pose.spine_target
    doc = {
        "format": SCHEMA,
        "body": {"name": body.name, "structure": structure_hash(body)},
        "kind": kind,
        "units": {"angles": "deg", "lengths": "m", "times": "s"},
        "position": position,
        "angles_deg": {n: degrees[..., i, :] for i, n in enumerate(body.segment_names)},
        "spine_target_deg": None if spine is None else np.degrees(np.asarray(spine, float)),
        "times": None if times is None else np.asarray(times, float),
        "status": _status_names(status),
        "residuals": residuals or {},
        "scale": scale or {},
        "overlays": overlays or {},
        "extra": extra or {},
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".json":
        path.write_text(json.dumps(_plain(doc), indent=1))
    else:
        arrays: dict[str, np.ndarray] = {}
        doc = _outline(doc, "", arrays)
        np.savez_compressed(path, document=np.asarray(json.dumps(doc)), **arrays)
    return path


def _status_names(status: Any) -> Any:
    """Enum members (or arrays of their values, without the enum) as names."""
    if status is None or isinstance(status, str):
        return status
    if hasattr(status, "name"):
        return status.name.lower()
    if isinstance(status, (list, tuple)) and all(hasattr(s, "name") for s in status):
        return [s.name.lower() for s in status]
    return _plain(status)


def _outline(value: Any, key: str, arrays: dict[str, np.ndarray]) -> Any:
    """The document with every array of more than INLINE numbers moved into `arrays`."""
    if isinstance(value, dict):
        return {k: _outline(v, f"{key}/{k}" if key else k, arrays) for k, v in value.items()}
    if hasattr(value, "__array__") and np.size(value) > INLINE:
        arrays[key] = np.asarray(value)
        return {"npz": key}
    return _plain(value)


def _inline(value: Any, archive: Any) -> Any:
    """The document with its {"npz": key} references read back from the archive."""
    if isinstance(value, dict):
        if set(value) == {"npz"}:
            return archive[value["npz"]]
        return {k: _inline(v, archive) for k, v in value.items()}
    return value


def read_document(path: Path) -> dict:
    """A pose file's document as written, its archived arrays read back (unchecked)."""
    if path.suffix == ".npz":
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such pose file")
        try:
            archive = np.load(path, allow_pickle=False)
            doc = json.loads(str(archive["document"]))
        except (OSError, ValueError, KeyError) as e:
            raise PoseFileError(
                f"{path}: not a diffbody pose archive ({e}); write one with diffbody.save_pose"
            ) from None
        return _inline(doc, archive)
    return read_json(path, "pose", PoseFileError)


def load_pose(path: str | Path, body: Body | None = None) -> PoseRecord:
    """Read a pose file written by `save_pose` (or by any diffbody command).

    Args:
        path: a ``*.json`` or ``*.npz`` pose file.
        body: the body to read it onto. Its structure must be the file's (same segments and
            tree; dimensions may differ): otherwise a `PoseFileError` names both bodies.
            None reads the rows in the file's segment order.

    Returns:
        a `PoseRecord`; its `pose` has float arrays (JAX), angles in rad.
    """
    path = Path(path)
    doc = read_document(path)

    def fail(what: str, fix: str = "write it with diffbody.save_pose") -> PoseFileError:
        return PoseFileError(f"{path}: {what}; {fix}")

    if not isinstance(doc, dict) or doc.get("format") != SCHEMA:
        found = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise fail(f"field 'format' is {found!r}, not {SCHEMA!r} (not a pose file)")
    for name in ("body", "kind", "position", "angles_deg"):
        if name not in doc:
            raise fail(f"field {name!r} is missing")
    kind, saved = doc["kind"], doc["body"]
    if kind not in KINDS:
        raise fail(f"field 'kind' is {kind!r}, not one of {KINDS}")
    names = list(doc["angles_deg"])
    if body is not None:
        if saved.get("structure") != structure_hash(body):
            raise fail(
                f"a pose of body {saved.get('name')!r} (structure {saved.get('structure')}, "
                f"{len(names)} segments), not of body {body.name!r} (structure "
                f"{structure_hash(body)}, {body.n_segments} segments)",
                "load it onto the body it was solved for (--body FILE, diffbody.load_body)",
            )
        names = list(body.segment_names)
    try:
        degrees = np.stack([np.asarray(doc["angles_deg"][n], float) for n in names], axis=-2)
        position = np.asarray(doc["position"], float)
    except (ValueError, TypeError) as e:
        raise fail(f"field 'angles_deg' or 'position' is not an array of numbers ({e})") from None
    lead = () if kind == "pose" else position.shape[:1]
    if degrees.shape != lead + (len(names), 3) or position.shape != lead + (3,):
        raise fail(
            f"kind {kind!r} with angles {degrees.shape} and position {position.shape}; "
            f"expected angles {lead + (len(names), 3)} and position {lead + (3,)}"
        )
    spine = doc.get("spine_target_deg")
    leaves = [jnp.asarray(position), jnp.asarray(np.radians(degrees))]
    if spine is not None:
        leaves.append(jnp.asarray(np.radians(np.asarray(spine, float))))
    # One pose builds the structure; unflattening gives it the file's leading axis (Pose's
    # annotations name one pose's shapes).
    single = Pose(*(leaf[(0,) * len(lead)] for leaf in leaves))
    pose = jax.tree.unflatten(jax.tree.structure(single), leaves)
    times = doc.get("times")
    status = doc.get("status")
    return PoseRecord(
        path=str(path),
        body_name=str(saved.get("name")),
        structure=str(saved.get("structure")),
        kind=kind,
        pose=pose,
        times=None if times is None else np.asarray(times, float),
        # A list in the document; an array of names where a long run's merge streamed it.
        status=tuple(str(s) for s in status) if isinstance(status, (list, np.ndarray)) else status,
        residuals={k: np.asarray(v) for k, v in (doc.get("residuals") or {}).items()},
        scale=dict(doc.get("scale") or {}),
        overlays={k: dict(v) for k, v in (doc.get("overlays") or {}).items()},
        extra=dict(doc.get("extra") or {}),
    )
