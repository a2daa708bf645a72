"""diffbody's compile options (diffbody._programs): the same answers as XLA's defaults, and
XLA's defaults where the installed XLA does not know them."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compiles import counted_compiles

import diffbody as db
from diffbody import _programs
from diffbody.ik._attempt import Settings, attempt_round
from diffbody.ik._phases import phase_layouts
from diffbody.ik._reach import constrained_targets
from diffbody.problem._targets import Target, resolve_targets


def _standing_round(body):
    """The arguments of one round of the standing (trunk) phase of a far, low reach."""
    rest = body.rest_pose()
    target = Target.position("left_hand.palm", (0.9, 0.3, 0.7))
    ts, _ = resolve_targets(body, [target])
    phase_targets = constrained_targets(body, ts, [target], rest, True)
    layouts = phase_layouts(
        body, phase_targets, spine=True, free_root=False, segments=None, stand=True
    )
    assert layouts[-1].standing
    settings = Settings(jnp.asarray(1e-3), jnp.asarray(np.deg2rad(1.0)))
    x = jnp.zeros(layouts[-1].n_free)
    start = (np.asarray(0), np.asarray(True), np.asarray(10, np.int32))
    return (body, layouts[-1], rest, phase_targets[-1], x, *start, settings)


def test_the_compile_options_give_xla_defaults_answers(male50):
    """A standing round compiled with `CPU_OPTIONS` and with XLA's defaults: the same free
    vector, verdict and pose to float rounding. (The default's fusion emitters asked for by
    name: the default tier turns them off for every program, tests/conftest.py.)"""
    args = _standing_round(male50)
    x_fast, done_fast, a_fast = _programs.compiled(attempt_round)(*args)
    defaults = {name: not off for name, off in _programs.CPU_OPTIONS.items()}
    x_plain, done_plain, a_plain = eqx.filter_jit(attempt_round, compiler_options=defaults)(*args)
    assert bool(done_fast) == bool(done_plain)
    np.testing.assert_allclose(x_fast, x_plain, rtol=0, atol=1e-8)
    np.testing.assert_allclose(a_fast.pose.angles, a_plain.pose.angles, rtol=0, atol=1e-8)
    np.testing.assert_allclose(a_fast.err_p, a_plain.err_p, rtol=0, atol=1e-9)


def test_an_option_xla_does_not_know_falls_back_to_the_defaults(monkeypatch):
    """An option the installed XLA refuses: the program compiles with the defaults, once
    refused, always the defaults; DIFFBODY_XLA_DEFAULTS=1 asks for them from the start."""
    monkeypatch.setattr(_programs, "CPU_OPTIONS", {"xla_no_such_option_anywhere": True})
    monkeypatch.setattr(_programs, "_REFUSED", [])
    f = _programs.compiled(lambda x: 2.0 * x)
    np.testing.assert_allclose(f(jnp.arange(3.0)), [0.0, 2.0, 4.0])
    assert len(_programs._REFUSED) == 1 and "No such compile option" in _programs._REFUSED[0]
    np.testing.assert_allclose(f(jnp.arange(2.0)), [0.0, 2.0])
    assert len(_programs._REFUSED) == 1
    monkeypatch.setattr(_programs, "_REFUSED", [])
    monkeypatch.setenv("DIFFBODY_XLA_DEFAULTS", "1")
    assert not _programs._use_options()
    g = _programs.compiled(lambda x: x + 1.0)
    np.testing.assert_allclose(g(jnp.zeros(2)), [1.0, 1.0])
    assert _programs._REFUSED == []


class _Out(eqx.Module):
    """An output with a static field and an optional array, as a solve's result has."""

    value: jnp.ndarray
    extra: jnp.ndarray | None
    names: tuple[str, ...] = eqx.field(static=True)


@pytest.fixture
def export_folder(tmp_path, monkeypatch):
    """A persistent cache of its own (where exported programs are kept), nothing loaded."""
    before = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", str(tmp_path))
    monkeypatch.setattr(_programs, "_LOADED", {})
    monkeypatch.setattr(_programs, "_SEEN", {})
    yield tmp_path / "diffbody-exported"
    jax.config.update("jax_compilation_cache_dir", before)


TRACED: list[float] = []


def _sine(x, scale: float):
    """A module-level function (a closure is never exported): records each trace."""
    TRACED.append(scale)
    return _Out(value=scale * jnp.sin(x), extra=None, names=("a", "b"))


def test_a_kept_program_is_read_back_without_tracing(export_folder, monkeypatch):
    """The first call traces and exports the program; a later process (the loaded programs
    forgotten) reads it back and runs it without tracing the Python function, with the
    same answer, static fields and None included; edited source exports anew; a closure is
    never exported."""
    TRACED.clear()
    f = _programs.compiled(_sine)
    x = jnp.linspace(0.0, 1.0, 5)
    first = f(x, 2.0)
    assert TRACED == [2.0] and len(list(export_folder.glob("*.bin"))) == 1
    monkeypatch.setattr(_programs, "_LOADED", {})
    again = f(x, 2.0)
    assert TRACED == [2.0]
    assert again.names == ("a", "b") and again.extra is None
    np.testing.assert_allclose(again.value, first.value, rtol=0, atol=0)
    f(x, 3.0)  # another static argument: another program
    assert TRACED == [2.0, 3.0] and len(list(export_folder.glob("*.bin"))) == 2
    monkeypatch.setattr(_programs, "_LOADED", {})
    monkeypatch.setattr(_programs, "_SEEN", {})
    monkeypatch.setattr(_programs, "_source", lambda: "edited")
    f(x, 2.0)
    assert TRACED == [2.0, 3.0, 2.0]
    offset = 1.0
    _programs.compiled(lambda x: x + offset)(x)
    assert len(list(export_folder.glob("*.bin"))) == 3


class _Shared(eqx.Module):
    """Static fields that may or may not share one object."""

    a: tuple = eqx.field(static=True)
    b: tuple = eqx.field(static=True)


def _labelled(x, labels: _Shared):
    TRACED.append(labels.a)
    return x * len(labels.a)


def test_equal_static_arguments_are_one_program_whether_or_not_they_share_objects(
    export_folder, monkeypatch
):
    """Regression: the key pickled the static arguments with pickle's memo, so a body
    whose fields share a tuple and the same body rebuilt (equal, not shared) were two
    programs: a later process missed what an earlier one kept."""
    TRACED.clear()
    f = _programs.compiled(_labelled)
    shared = tuple("left right".split())
    x = jnp.arange(3.0)
    f(x, _Shared(shared, shared))
    monkeypatch.setattr(_programs, "_LOADED", {})  # a later process
    monkeypatch.setattr(_programs, "_SEEN", {})
    f(x, _Shared(tuple("left right".split()), tuple("left right".split())))
    assert TRACED == [shared] and len(list(export_folder.glob("*.bin"))) == 1


def _affine(a, b):
    return 2.0 * a + b


def test_arrays_committed_to_the_device_or_not_are_one_compiled_program(export_folder):
    """Regression: jit compiled a kept program once per pattern of arguments committed to
    the device or not (a body read from its file, and the body a solve returned), the same
    program two or three times over a workflow: the arguments' device is now given."""
    f = _programs.compiled(_affine)
    device = jax.local_devices()[0]
    loose = jax.device_put(np.ones(3, np.float32))
    committed = jax.device_put(np.ones(3, np.float32), device)
    with counted_compiles() as compiles:
        for args in (
            (loose, loose),
            (committed, loose),
            (loose, committed),
            (np.ones(3, np.float32), committed),
        ):
            np.testing.assert_allclose(f(*args), [3.0, 3.0, 3.0])
    assert len(compiles) == 1


def test_a_damaged_kept_program_is_exported_again(export_folder, monkeypatch):
    """A file cut short (a full disk, a killed process) is traced and written again."""
    f = _programs.compiled(lambda x: x + 1.0)
    f(jnp.zeros(3))
    (path,) = export_folder.glob("*.bin")
    path.write_bytes(path.read_bytes()[:20])
    monkeypatch.setattr(_programs, "_LOADED", {})
    np.testing.assert_allclose(f(jnp.zeros(3)), [1.0, 1.0, 1.0])
    assert len(path.read_bytes()) > 20


def test_a_reach_read_back_from_its_kept_programs_is_the_same(export_folder, male50, monkeypatch):
    """solve_reach through kept programs, then read back as a new process would: the same
    pose, status and reached flags."""
    target = [Target.position("left_hand.palm", (0.35, 0.3, 1.1))]
    first = db.solve_reach(male50, target)
    assert any(export_folder.glob("*.bin"))
    monkeypatch.setattr(_programs, "_LOADED", {})
    again = db.solve_reach(male50, target)
    assert int(again.status) == int(first.status) == 0
    np.testing.assert_array_equal(again.pose.angles, first.pose.angles)
    assert again.constraint_names == first.constraint_names


def _scaled_rows(x, w, scale: float):
    """Rows x (n, 3) times a shared w (3,): records each trace."""
    TRACED.append(x.shape)
    return scale * x * w


def _by_row_count(x):
    """A function whose row count decides a branch: no symbolic row count goes through."""
    return x + 1.0 if x.shape[0] > 4 else x - 1.0


def test_row_counts_share_one_trace_and_one_kept_program(export_folder):
    """A function compiled with `rows` is traced and kept once for every row count, the
    shared argument's shape fixed: XLA compiles each row count (two here), and the answers
    are the NumPy reference's. One whose row count decides a branch cannot be exported
    with a symbolic count: it takes the plain path, each count its own trace and answer."""
    TRACED.clear()
    f = _programs.compiled(_scaled_rows, rows=(0,))
    w = np.asarray([1.0, 2.0, 3.0], np.float32)
    with counted_compiles() as compiles:
        for n in (4, 8, 4):
            x = np.arange(3 * n, dtype=np.float32).reshape(n, 3)
            np.testing.assert_allclose(f(x, w, 2.0), 2.0 * x * w, rtol=1e-6)
    assert len(TRACED) == 1 and not isinstance(TRACED[0][0], int)  # traced symbolically
    assert len(compiles) == 2 and len(list(export_folder.glob("*.bin"))) == 1
    g = _programs.compiled(_by_row_count, rows=(0,))
    for _ in range(2):
        np.testing.assert_allclose(g(np.zeros((8, 2), np.float32)), np.ones((8, 2)))
        np.testing.assert_allclose(g(np.zeros((2, 2), np.float32)), -np.ones((2, 2)))
    assert len(list(export_folder.glob("*.bin"))) == 1
    assert sum(key is None for key in _programs._SEEN.values()) == 2  # not tried again
