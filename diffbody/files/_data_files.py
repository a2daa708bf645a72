"""The data files: where the embedded ones are (`data_file`), reading a JSON file
(`read_json`), and the field checks every reader shares (`Where`; a marker set's reader
subclasses it for its own error).

Every error of a body file or spine database is a `BodyFileError` naming the file, the
entry, the field and what is expected, e.g. ``body.json: segment 'left_forearm'
(segments[12]), field 'length': must lie in [0.0001, 10] m, got -0.2``. A file that cannot
be read (missing aside) or is not UTF-8 JSON is a `BodyFileError` naming the file too.
"""

import csv
import io
import json
import math
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np


def data_file(name: str) -> Path:
    """A file of the embedded data: data/ of a source checkout or of the installed wheel."""
    for folder in (
        Path(__file__).resolve().parents[2] / "data",  # a source checkout
        Path(str(resources.files("diffbody"))) / "data",  # an installed wheel
    ):
        if (folder / name).is_file():
            return folder / name
    raise FileNotFoundError(f"diffbody: embedded data file {name!r} not found")


def data_rows(name: str) -> list[dict[str, str]]:
    """The rows of an embedded CSV table ({column: text}), its '#' comment lines dropped."""
    path = data_file(name)
    text = read_text(path, "data table", ValueError, "an embedded table is UTF-8 CSV")
    return list(csv.DictReader(line for line in text.splitlines() if not line.startswith("#")))


def data_array(name: str, header_lines: int) -> np.ndarray:
    """The numbers of an embedded CSV table after its `header_lines` lines, (rows, columns)."""
    text = read_text(data_file(name), "data table", ValueError, "an embedded table is UTF-8 CSV")
    return np.loadtxt(io.StringIO(text), delimiter=",", skiprows=header_lines, ndmin=2)


class _Object(dict):
    """A JSON object that remembers the keys it was given twice (json keeps the last)."""

    duplicates: tuple[str, ...] = ()


def json_object(pairs: list[tuple[str, Any]]) -> _Object:
    obj = _Object(pairs)
    keys = [k for k, _ in pairs]
    obj.duplicates = tuple(sorted({k for k in keys if keys.count(k) > 1}))
    return obj


class BodyFileError(ValueError):
    """A body file that cannot be loaded; the message says where and how to fix it."""


class Where:
    """Where we are in the file, for error messages."""

    def __init__(self, path: str, entry: str):
        self.path, self.entry = path, entry

    def fail(self, field: str | None, message: str) -> BodyFileError:
        at = f", field {field!r}" if field else ""
        return BodyFileError(f"{self.path}: {self.entry}{at}: {message}")

    def fields(self, obj: Any, required: set[str], optional: set[str] = frozenset()) -> None:
        """obj is an object with every required field, no unknown one, none given twice; the
        free-text fields `source` and `description`, where allowed and given, are text."""
        if not isinstance(obj, dict):
            raise self.fail(None, f"must be a JSON object, got {type(obj).__name__}")
        for f in getattr(obj, "duplicates", ()):
            raise self.fail(f, "given twice; keep one")
        for f in sorted(required - obj.keys()):
            raise self.fail(f, "missing (required)")
        for f in sorted(obj.keys() - required - optional):
            allowed = ", ".join(sorted(required | optional))
            raise self.fail(f, f"unknown field; allowed fields are: {allowed}")
        for f in ("source", "description"):
            if f in obj:
                self.string(obj, f)

    def string(self, obj: dict, field: str) -> str:
        v = obj[field]
        if not isinstance(v, str) or not v:
            raise self.fail(field, f"must be a non-empty string, got {v!r}")
        return v

    def number(
        self,
        obj: dict,
        field: str,
        *,
        positive=False,
        within: tuple[float, float] | None = None,
        unit: str = "",
    ) -> float:
        """A finite number; > 0 when `positive`; in [lo, hi] `unit` when `within` is given."""
        v = _finite(self, field, obj[field])
        if positive and v <= 0:
            raise self.fail(field, f"must be > 0, got {v}")
        if within is not None:
            bounded(self, field, v, within, unit)
        return v

    def numbers(self, obj: dict, field: str, n: int, what: str) -> list[float]:
        """A list of n finite numbers (`what` names them, e.g. "[x, y, z]")."""
        v = obj[field]
        if not isinstance(v, list) or len(v) != n:
            raise self.fail(field, f"must be a list of {n} numbers {what}, got {v!r}")
        return [_finite(self, field, x) for x in v]

    def vector(
        self, obj: dict, field: str, *, unit=False, bound: float | None = None
    ) -> np.ndarray:
        """[x, y, z]: finite, each |coordinate| <= bound; `unit` normalises a direction."""
        a = np.asarray(self.numbers(obj, field, 3, "[x, y, z]"))
        if bound is not None and np.max(np.abs(a)) > bound:
            raise self.fail(
                field, f"every coordinate must lie in [-{bound:g}, {bound:g}] m, got {a.tolist()}"
            )
        if unit:
            scaled = a / max(np.max(np.abs(a)), 1e-300)  # |a| of 1e300 must not overflow
            if np.max(np.abs(a)) < 1e-9:
                raise self.fail(field, f"must be a non-zero direction, got {a.tolist()}")
            a = scaled / np.linalg.norm(scaled)
        return a

    def range_deg(self, obj: dict, field: str, bound: float = 180.0) -> tuple[float, float]:
        """[lo, hi] in degrees within [-bound, bound], returned in radians."""
        lo, hi = self.numbers(obj, field, 2, "[lo, hi] in degrees")
        if lo > hi:
            raise self.fail(field, f"inverted limits: lo {lo} > hi {hi}; expected lo <= hi")
        if lo < -bound or hi > bound:
            raise self.fail(
                field, f"must lie within [-{bound:g}, {bound:g}] degrees, got {[lo, hi]}"
            )
        return math.radians(lo), math.radians(hi)


def _finite(where: Where, field: str, v: Any) -> float:
    """A JSON number as a finite float (not a bool, not a string, not 1e400 or NaN)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise where.fail(field, f"must be a number, got {type(v).__name__} {v!r}")
    try:
        x = float(v)  # an integer too large for a float raises OverflowError
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        shown = v if isinstance(v, float) else f"an integer of {len(str(v))} digits"
        raise where.fail(field, f"must be a finite number, got {shown}")
    return x


def bounded(where: Where, field: str, x: float, bound, unit: str = "") -> float:
    """x within bound, (lo, hi) or b for [-b, b], in `unit`; else a BodyFileError."""
    lo, hi = bound if isinstance(bound, tuple) else (-bound, bound)
    if not lo <= x <= hi:
        unit = f" {unit}" if unit else ""
        raise where.fail(field, f"must lie in [{lo:g}, {hi:g}]{unit}, got {x:g}")
    return x


def read_text(
    path, kind: str, error: type[ValueError], saved_as: str, *, unit: str = "line", form: str = ""
) -> str:
    """The text of a `kind` file (a byte-order mark dropped): how every reader opens a file.

    A missing file is a FileNotFoundError ("PATH: no such KIND file"); a folder, bytes that
    are not UTF-8 and any other failure to read are `error`s naming the file, and for bad
    bytes the `unit` ("line", or "row" for a CSV) and byte, and how the file is meant to be
    saved (`saved_as`, e.g. "a TRC file is tab-separated text"); a folder is told what file
    was expected, its `form` ("JSON") named."""
    shown = str(path)
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"{shown}: no such {kind} file") from None
    except IsADirectoryError:
        what = f"{kind} {form}".strip()
        article = "an" if what[0] in "aeiouAEIOU" else "a"
        raise error(f"{shown}: is a directory; expected {article} {what} file") from None
    except OSError as e:
        raise error(f"{shown}: cannot read the {kind} file: {e.strerror}") from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        raise error(
            f"{shown}: {unit} {line}: not UTF-8 text (byte 0x{data[e.start]:02x} at offset "
            f"{e.start}); {saved_as}"
        ) from None


def read_json(path: Path, kind: str, error: type[ValueError] = BodyFileError) -> Any:
    """The JSON document of a `kind` ("body", "spine", "marker set") file; every failure names
    the file and raises `error`. Objects keep the keys given twice (`_Object.duplicates`) for
    `Where.fields` to reject."""
    shown = str(path)
    text = read_text(path, kind, error, f"a {kind} file is JSON saved as UTF-8", form="JSON")
    try:
        return json.loads(text, object_pairs_hook=json_object)
    except json.JSONDecodeError as e:
        raise error(
            f"{shown}: not valid JSON: {e.msg} at line {e.lineno} column {e.colno}"
        ) from None
    except RecursionError:
        raise error(f"{shown}: not valid JSON: nested too deeply") from None
