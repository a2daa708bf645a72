"""What a long run records of what produced it, and how a resumed run checks it: every run
(the reach batch's results CSV, a folder of mocap trials, a `ChunkStore`'s run.json) keeps
``key: value`` fields, and goes on with its output only when the fields that decide a row
are the same, else it is refused, naming in words each thing that changed."""

import hashlib

from ..files._pose_file import structure_hash
from ._streaming import tree_hash

BODY_KEYS = ("body", "body-structure", "body-dimensions")


def body_fields(body) -> list[tuple[str, str]]:
    """The body's fields: its name, its structure and its dimensions (hashes)."""
    return [
        ("body", body.name),
        ("body-structure", structure_hash(body)),
        ("body-dimensions", tree_hash(body)),
    ]


def file_sha256(path) -> str:
    """The SHA-256 of a file's bytes (hex), read a megabyte at a time."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def header_changes(
    old: dict[str, str], new: dict[str, str], inputs: dict[str, str], settings: dict[str, str]
) -> list[str]:
    """What differs between the recorded fields (`old`) and this run's (`new`), each told in
    words; empty when the run may go on. `inputs`: {a hash field: what it hashes, e.g.
    "the input file"}; the body's fields (`body_fields`), where the run has them, are told
    as one change; `settings`: {a field: what the setting is called where it was given}."""
    told = []
    for key, what in inputs.items():
        if old.get(key) != new[key]:
            was = old.get(key, "(not recorded)")[:16]
            told.append(f"{what} changed (sha256 {was}... vs {new[key][:16]}...)")
    if any(key in new and old.get(key) != new[key] for key in BODY_KEYS):

        def said(h):
            return (
                f"{h.get('body')}: structure {h.get('body-structure')}, "
                f"dimensions {h.get('body-dimensions')}"
            )

        told.append(f"the body changed ({said(old)} vs {said(new)})")
    for key, name in settings.items():
        if old.get(key) != new[key]:
            told.append(f"{name} changed from {old.get(key, '(not recorded)')} to {new[key]}")
    return told
