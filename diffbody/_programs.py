"""How diffbody compiles its large programs (docs/design.md, section 3, "Programs").

Two things cost a process its start: XLA's compile, and tracing and lowering the Python
functions before it, which JAX's persistent compilation cache does not save.

- XLA's CPU backend spends most of a solve program's compile in its fusion emitters:
  compiled without them (`xla_cpu_use_fusion_emitters=False`, a per-program compile option,
  so nothing else in the process changes) a reach round compiles in about half the time
  (benchmarks/startup.py) and gives the same answers to float rounding
  (tests/test_programs.py). The option is XLA's, not a stable API: where the installed XLA
  does not know it, the program compiles with XLA's defaults; `DIFFBODY_XLA_DEFAULTS=1` asks
  for the defaults everywhere.
- Where JAX's persistent compilation cache is on (`jax_compilation_cache_dir`; importing
  diffbody turns it on, `keep_compiled`), each program is also kept as a `jax.export`
  serialisation beside it, keyed by the function, its static arguments (pickled), its array
  shapes, and the versions of JAX and of diffbody's own source: a later process
  deserialises it and calls it instead of tracing and lowering the Python function again.
  Anything else (another version, a traced or sharded argument, a closure, static
  arguments that do not pickle) takes the plain path. A batch's programs are exported with
  their rows' axis symbolic (`compiled(fn, rows=...)`): a chunk and the smaller chunk of
  the rows a batch retries are traced once, one file, where each was 1.3-1.8 s of tracing
  and lowering (XLA still compiles each row count).
- Not the compiled executable itself (`jax.experimental.serialize_executable`), though
  loading one would also skip the lowering and the cache's key (the README command cached:
  1.8 s instead of 3.0 s): in jaxlib 0.10.2 a CPU executable read back in another process
  misses some of its kernels ("NOT_FOUND: Function gather.43_kernel not found") or
  crashes the process, with or without XLA flags.
"""

import contextlib
import functools
import hashlib
import inspect
import io
import os
import pickle
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlib.version
from jax.errors import InconclusiveDimensionOperation

CPU_OPTIONS = {"xla_cpu_use_fusion_emitters": False}


def keep_compiled() -> None:
    """Turn on JAX's persistent compilation cache unless the process chose one: the folder
    $JAX_COMPILATION_CACHE_DIR when set, else $XDG_CACHE_HOME/diffbody/jax
    (~/.cache/diffbody/jax); DIFFBODY_NO_CACHE=1 leaves it off. Called when diffbody is
    imported and by the command line, so that a later process reads back what an earlier one
    compiled and exported. Every compiled function is kept, however quick to compile (JAX
    keeps only those over 1 s by default): reading one back costs a few milliseconds,
    compiling it tens."""
    if os.environ.get("DIFFBODY_NO_CACHE") == "1":
        return
    if not jax.config.jax_compilation_cache_dir:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
        jax.config.update("jax_compilation_cache_dir", str(base / "diffbody" / "jax"))
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def compiled(fn, rows: tuple[int, ...] = ()):
    """`eqx.filter_jit(fn)`, compiled with `CPU_OPTIONS` on the CPU while XLA accepts them
    (then with XLA's defaults, for the rest of the process), and kept exported beside the
    persistent compilation cache when there is one (module docstring). `rows`: the
    positions of the arguments whose every array has a leading axis of rows (a batch's
    chunk): exported with that axis symbolic, so that every row count is traced once and
    kept in one file (XLA still compiles each row count)."""
    fast = eqx.filter_jit(fn, compiler_options=CPU_OPTIONS)
    plain = eqx.filter_jit(fn)

    def run(args):
        return with_options(fast, plain, args)

    # A closure's captured values are not among its arguments: it is never exported (a
    # decorator's wrapper, a type checker's, is looked through).
    exportable = not getattr(inspect.unwrap(fn), "__closure__", None)

    @functools.wraps(fn)
    def call(*args):
        if is_traced(args):
            return plain(*args)
        folder = _export_folder()
        if folder is None or not exportable or not _can_serialise():
            return run(args)
        return _exported_call(fn, folder, args, run, rows)

    return call


_REFUSED: list[str] = []  # XLA refused CPU_OPTIONS once: the defaults from then on


def with_options(fast, plain, args: tuple):
    """fast(*args) (compiled with `CPU_OPTIONS`) where they apply, else plain(*args)."""
    if not _use_options():
        return plain(*args)
    try:
        return fast(*args)
    except jax.errors.JaxRuntimeError as e:
        if "No such compile option" not in str(e):
            raise
        _REFUSED.append(str(e))
        return plain(*args)
    except ValueError as e:
        # Inside another jit (only a top-level jit takes compile options): the outer
        # program's options hold.
        if "top-level" not in str(e):
            raise
        return plain(*args)


def _use_options() -> bool:
    return (
        not _REFUSED
        and os.environ.get("DIFFBODY_XLA_DEFAULTS", "") in ("", "0")
        and jax.default_backend() == "cpu"
    )


@functools.cache
def _can_serialise() -> bool:
    """Whether jax.export can write its programs (it needs flatbuffers)."""
    try:
        import flatbuffers  # noqa: F401
    except ImportError:
        return False
    return True


def is_traced(*trees) -> bool:
    """Whether any leaf of the trees is a JAX tracer (under jit, grad, vmap)."""
    return any(isinstance(a, jax.core.Tracer) for a in jax.tree.leaves(trees))


def _export_folder() -> Path | None:
    base = jax.config.jax_compilation_cache_dir
    return None if not base else Path(base) / "diffbody-exported"


# --- exported programs ---------------------------------------------------------------------
# (key, device id) -> (the compiled calls, the output's structure)
_LOADED: dict[tuple, tuple] = {}
# (fn, the arguments' structure and static values, the arrays' shapes, dtypes and
# placements) -> key, or None for the plain path: what a warm call looks up, in microseconds,
# instead of pickling and hashing its static arguments again.
_SEEN: dict[tuple, str | None] = {}


def _exported_call(fn, folder: Path, args: tuple, run, rows: tuple[int, ...] = ()):
    leaves, structure = jax.tree.flatten(args)
    is_array = [eqx.is_array(a) for a in leaves]
    seen = (fn, structure, tuple(_spec(a) if m else a for a, m in zip(leaves, is_array)))
    try:
        key = _SEEN[seen] if seen in _SEEN else _first_key(fn, args, seen, rows)
    except TypeError:  # a static argument that cannot be hashed
        key = _first_key(fn, args, None, rows)
    if key is None:
        return run(args)
    arrays = [a for a, m in zip(leaves, is_array) if m]
    # The arguments' one device, given to `jax.jit` as their placement: left to infer it,
    # jit compiles once per pattern of arrays committed to the device or not (a loaded
    # body's and a solve's outputs), the same program two or three times.
    placed = next((a.sharding for a in arrays if isinstance(a, jax.Array)), None)
    device = placed or jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    loaded = (key, next(iter(device.device_set)).id)
    if loaded not in _LOADED:
        dynamic, static = eqx.partition(args, eqx.is_array)
        treedef = jax.tree.structure(dynamic)
        path = folder / f"{key}.bin"
        try:
            blob, template = pickle.loads(path.read_bytes())
            exported = jax.export.deserialize(blob)
        except (OSError, EOFError, pickle.UnpicklingError, ValueError, TypeError):
            exported, template = _export(fn, static, treedef, _polymorphic(args, rows))
            if exported is None:
                with contextlib.suppress(TypeError):  # an unhashable static argument
                    _SEEN[seen] = None  # the plain path from now on, not exported again
                return run(args)
            _save(path, exported, template)

        def run_exported(*a):
            return exported.call(*a)

        run_exported.__name__ = getattr(fn, "__name__", "exported")  # fn's name in the logs
        calls = (
            jax.jit(run_exported, in_shardings=device, compiler_options=CPU_OPTIONS),
            jax.jit(run_exported, in_shardings=device),
        )
        _LOADED[loaded] = (calls, jax.tree.structure(template))
    (fast, plain), out_structure = _LOADED[loaded]
    return jax.tree.unflatten(out_structure, with_options(fast, plain, tuple(arrays)))


def _spec(a) -> tuple:
    """What of an array decides its program: shape, dtype, weak type, placement."""
    placement = a.sharding if isinstance(a, jax.Array) else None
    return (a.shape, a.dtype, getattr(a, "weak_type", False), placement)


def _first_key(fn, args: tuple, seen: tuple | None, rows: tuple[int, ...] = ()) -> str | None:
    """The key of a call not seen before (None: the plain path), remembered under `seen`."""
    dynamic, static = eqx.partition(args, eqx.is_array)
    leaves, treedef = jax.tree.flatten(dynamic)
    if any(len(a.sharding.device_set) > 1 for a in leaves if isinstance(a, jax.Array)):
        key = None  # sharded over several devices: exported for one
    else:
        key = _key(fn, static, treedef, _polymorphic(args, rows))
    if seen is not None:
        _SEEN[seen] = key
    return key


def _polymorphic(args: tuple, rows: tuple[int, ...]) -> list[jax.ShapeDtypeStruct]:
    """The shapes and dtypes of the arguments' arrays, the leading axis of those of the
    arguments at `rows` one symbolic size ("rows")."""
    (n,) = jax.export.symbolic_shape("rows") if rows else (None,)
    specs = []
    for i, arg in enumerate(args):
        for a in jax.tree.leaves(eqx.filter(arg, eqx.is_array)):
            shape = jnp.shape(a)
            dtype = jnp.result_type(a)  # canonical: float64 is float32 without x64
            specs.append(jax.ShapeDtypeStruct((n, *shape[1:]) if i in rows else shape, dtype))
    return specs


def _export(fn, static, treedef, specs):
    """The exported program of fn at arguments of these shapes and its output's structure
    (a pytree of `jax.ShapeDtypeStruct`, which pickles; a symbolic size as 0), or None when
    its output holds non-arrays or a symbolic size does not go through fn (its shape
    decides a branch)."""
    shapes: list = []

    def flat(*dynamic_leaves):
        out = fn(*eqx.combine(jax.tree.unflatten(treedef, dynamic_leaves), static))
        shapes.append(jax.tree.map(_shape_of, out))
        return jax.tree.leaves(out)

    try:
        exported = jax.export.export(jax.jit(flat))(*specs)
    except InconclusiveDimensionOperation:
        return None, None
    out = shapes[0]
    if not all(isinstance(a, jax.ShapeDtypeStruct) for a in jax.tree.leaves(out)):
        return None, None
    return exported, out


def _shape_of(a):
    if not eqx.is_array(a):
        return a
    shape = tuple(d if isinstance(d, int) else 0 for d in jnp.shape(a))
    return jax.ShapeDtypeStruct(shape, jnp.result_type(a))


def _save(path: Path, exported, template) -> None:
    """Written to a temporary name and renamed: a reader never sees half a file."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_bytes(pickle.dumps((exported.serialize(), template)))
        tmp.replace(path)
    except OSError:
        pass  # a read-only cache: the program still runs, and is exported again next time


def _key(fn, static, treedef, specs: list[jax.ShapeDtypeStruct]) -> str | None:
    """What the program depends on, hashed: the function, its static arguments (pickled:
    every field, in full), the arrays' structure, shapes (`_polymorphic`) and dtypes, the
    versions. None when the static arguments do not pickle (a function made at run time)."""
    try:
        static_bytes = _pickled(static)
    except (pickle.PicklingError, AttributeError, TypeError, ValueError):
        return None
    spec = [(str(a.shape), str(a.dtype)) for a in specs]
    code = inspect.unwrap(fn).__code__
    where = (fn.__module__, fn.__qualname__, code.co_filename, str(code.co_firstlineno))
    parts = (*where, str(treedef), repr(spec), jax.__version__, _source())
    # What else changes a lowering: the backend, the dtypes, a matmul precision.
    config = jax.config
    parts += (jaxlib.version.__version__, jax.default_backend(), str(config.jax_enable_x64))
    parts += (str(config.jax_default_matmul_precision), str(config.jax_numpy_dtype_promotion))
    h = hashlib.sha256(static_bytes)
    h.update("\n".join(parts).encode())
    return h.hexdigest()[:32]


def _pickled(static) -> bytes:
    """The static arguments pickled without pickle's memo: equal arguments give equal bytes
    whether or not they share objects (a body whose fields share one tuple, and the same body
    rebuilt, are one program). ValueError for a cyclic object (the plain path)."""
    buffer = io.BytesIO()
    pickler = pickle.Pickler(buffer, protocol=4)
    pickler.fast = True
    pickler.dump(static)
    return buffer.getvalue()


@functools.cache
def _source() -> str:
    """A hash of diffbody's own source: an edited package exports its programs anew."""
    h = hashlib.sha256()
    root = Path(__file__).parent
    for path in sorted(root.rglob("*.py")):
        h.update(path.read_bytes())
    return h.hexdigest()
