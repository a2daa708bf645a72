"""A file of reach targets, read a block of rows at a time: a CSV of x,y,z per effector (a
header row optional), or a Parquet file of 3k numeric columns (with pyarrow installed).

Memory holds one block, whatever the file's length: `target_chunks` feeds a batch solve,
`scan_targets` checks every row, counts them and takes the file's SHA-256 before any solve
(a malformed row is told before hours of solving, not at its chunk). Errors are ValueErrors
that name the file, and the row and column where there is one.
"""

import codecs
import csv
import hashlib
import io
import os

import numpy as np

BLOCK_ROWS = 8192  # rows per block read from the file


def _csv_lines(path: str, digest=None, block: int = 1 << 20):
    """The targets file's text lines, decoded a block of whole lines at a time (a UTF-8
    byte-order mark dropped); every byte read goes into `digest` (a hashlib object) when
    given."""
    lines_before, rest, first = 0, b"", True
    with open(path, "rb") as f:
        while True:
            read = f.read(block)
            if digest is not None:
                digest.update(read)
            if first and read.startswith(codecs.BOM_UTF8):
                read = read[len(codecs.BOM_UTF8) :]  # a spreadsheet's byte-order mark is no data
            first, data = False, rest + read
            if not data:
                return
            # Whole lines only (so no character is cut either), all that is left at the end.
            cut = data.rfind(b"\n") + 1 if read else len(data)
            chunk, rest = data[:cut], data[cut:]
            if not chunk:
                continue
            try:
                text = chunk.decode("utf-8")
            except UnicodeDecodeError as e:
                line = lines_before + chunk[: e.start].count(b"\n") + 1
                raise ValueError(
                    f"{path}: row {line}: not UTF-8 text (byte {chunk[e.start]:#04x}); "
                    "save the targets as a plain UTF-8 CSV"
                ) from None
            lines_before += chunk.count(b"\n")
            # A lone \r ends a line too (old spreadsheets), as when the file is read whole.
            yield from io.StringIO(text, newline="")


def _csv_rows(path: str, k: int, digest=None):
    """The rows of a CSV of x,y,z per effector (header optional), each a list of 3k floats,
    checked as they are read; errors name the file, and the row and column where there is
    one."""
    example = ",".join(["0.35,0.30,1.10"] * k)
    shape = (
        f"each row is x,y,z in metres for each effector ({3 * k} columns), "
        f"comma-separated, e.g. {example}"
    )

    def number(cell):
        try:
            return float(cell)
        except ValueError:
            return None

    seen = {"bytes": False, "text": False}

    def lines():
        for line in _csv_lines(path, digest):
            seen["bytes"] = True
            seen["text"] = seen["text"] or bool(line.strip())
            yield line

    n, header = 0, False
    reader = csv.reader(lines())
    for row in reader:
        line = reader.line_num
        row = [c.strip() for c in row]
        if len(row) == 3 * k:
            try:  # the common row, all numbers: none of the checks below can fail it
                values = [float(c) for c in row]
            except ValueError:
                pass
            else:
                n += 1
                yield values
                continue
        if not row or all(c == "" for c in row):
            continue
        for sep, name in ((";", "semicolons"), ("\t", "tabs")):
            if any(sep in c for c in row):
                raise ValueError(
                    f"{path}: row {line}: columns are separated by commas, not {name}; {shape}"
                )
        if any(len(c.split()) > 1 and all(number(x) is not None for x in c.split()) for c in row):
            raise ValueError(
                f"{path}: row {line}: columns are separated by commas, not spaces; {shape}"
            )
        values = [number(c) for c in row]
        if not n and not header and all(v is None for v in values):
            header = True  # the first row, all names
            continue
        if len(row) != 3 * k:
            col = min(len(row), 3 * k) + 1
            raise ValueError(
                f"{path}: row {line}, column {col}: expected {3 * k} columns "
                f"(x,y,z for each of {k} effector(s)), got {len(row)}"
            )
        for col, (cell, v) in enumerate(zip(row, values), start=1):
            if cell == "":
                raise ValueError(f"{path}: row {line}, column {col}: empty cell")
            if v is None:
                raise ValueError(f"{path}: row {line}, column {col}: not a number: {cell!r}")
        n += 1
        yield values
    if not seen["text"]:
        what = "the file is empty" if not seen["bytes"] else "only blank lines"
        raise ValueError(f"{path}: no target rows, {what}; {shape}")
    if not n:
        what = "a header but no target rows" if header else "no target rows"
        raise ValueError(f"{path}: {what}; {shape}")


def _is_parquet(path: str) -> bool:
    return path.lower().endswith((".parquet", ".pq"))


def _parquet_blocks(path: str, k: int):
    """A Parquet file's rows as float arrays (m, 3k), a record batch at a time."""
    try:
        import pyarrow.parquet as pq
        import pyarrow.types as pt
    except ImportError:
        raise ValueError(
            f"{path}: reading Parquet needs pyarrow; pip install pyarrow, or give a CSV"
        ) from None
    try:
        f = pq.ParquetFile(path)
    except Exception as e:  # pyarrow's own errors: not a Parquet file, truncated
        raise ValueError(f"{path}: not a readable Parquet file ({e})") from None
    names = f.schema_arrow.names
    if len(names) != 3 * k:
        raise ValueError(
            f"{path}: expected {3 * k} columns (x,y,z for each of {k} effector(s)), got "
            f"{len(names)}: {', '.join(names)}"
        )
    for col, field in enumerate(f.schema_arrow, start=1):
        if not (pt.is_floating(field.type) or pt.is_integer(field.type)):
            raise ValueError(
                f"{path}: column {col} ({field.name}): {field.type}, not numbers; "
                "each column is a coordinate in metres"
            )
    at = 0
    for batch in f.iter_batches(batch_size=BLOCK_ROWS):
        columns = []
        for col, column in enumerate(batch.columns, start=1):
            if column.null_count:
                row = at + int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0])
                raise ValueError(f"{path}: row {row + 1}, column {col}: empty cell")
            columns.append(column.to_numpy(zero_copy_only=False).astype(float))
        at += batch.num_rows
        if batch.num_rows:
            yield np.stack(columns, axis=1)
    if not at:
        raise ValueError(f"{path}: no target rows")


def _blocks(path: str | os.PathLike, k: int, digest=None):
    """The file's rows as float arrays (m, 3k), m <= BLOCK_ROWS; for a CSV every byte read
    goes into `digest` when given (a Parquet file's bytes are hashed apart)."""
    path = os.fspath(path)
    if os.path.isdir(path):
        raise ValueError(f"{path}: is a directory; expected a CSV or Parquet file of targets")
    if _is_parquet(path):
        if digest is not None:
            with open(path, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    digest.update(block)
        yield from _parquet_blocks(path, k)
        return
    rows = []
    for values in _csv_rows(path, k, digest):
        rows.append(values)
        if len(rows) == BLOCK_ROWS:
            yield np.asarray(rows, float)
            rows = []
    if rows:
        yield np.asarray(rows, float)


def scan_targets(path: str | os.PathLike, k: int) -> tuple[str, int]:
    """Check every row of a targets file for `k` effectors; its SHA-256 (hex) and row count."""
    digest = hashlib.sha256()
    n = sum(len(block) for block in _blocks(path, k, digest))
    return digest.hexdigest(), n


def target_chunks(path: str | os.PathLike, k: int, chunk: int):
    """The targets as arrays (m, k, 3) of `chunk` rows (the last one fewer), read as they
    are needed: memory holds one chunk and one block."""
    held, count = [], 0
    for block in _blocks(path, k):
        held.append(block)
        count += len(block)
        while count >= chunk:
            rows = np.concatenate(held)
            yield rows[:chunk].reshape(-1, k, 3)
            held, count = [rows[chunk:]], count - chunk
    if count:
        yield np.concatenate(held).reshape(-1, k, 3)


def read_targets(path: str | os.PathLike, k: int) -> np.ndarray:
    """A whole targets file for `k` effectors as (n, k, 3) metres."""
    return np.concatenate(list(_blocks(path, k))).reshape(-1, k, 3)
