"""`bsfs_jax.cached_jit`: programs kept across processes (jax.export) give the same answers
as `filter_jit`, and fall back to it wherever they cannot be kept."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import bsfs_jax
from bsfs_jax import _prefetch, _programs


@bsfs_jax.cached_jit
def _poly(x, data, power: int):
    return {"value": jnp.sum(data["w"] * x**power), "grad": jax.grad(
        lambda y: jnp.sum(data["w"] * y**power))(x)}


@bsfs_jax.cached_jit(fast_compile=True)
def _poly_fast(x, data, power: int):
    return _poly.__wrapped__(x, data, power)


class _Box(eqx.Module):
    v: jax.Array


@bsfs_jax.cached_jit
def _boxed(x):
    return _Box(2.0 * x)  # an output that jax.export cannot write


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    monkeypatch.setattr(_programs, "_program_dir", lambda: tmp_path / "programs")
    monkeypatch.setattr(_programs, "_loaded", {})
    monkeypatch.setattr(_programs, "_pending", {})
    monkeypatch.setattr(_prefetch, "_waiting", [])
    return tmp_path


def _files(folder):
    return sorted((folder / "programs").glob("*.jaxexport"))


def test_kept_program_agrees_and_is_reused(cache_dir):
    x = np.linspace(0.0, 1.0, 5)
    data = {"w": np.arange(5.0)}
    want = eqx.filter_jit(_poly.__wrapped__)(x, data, 3)
    got = _poly(x, data, 3)
    assert len(_files(cache_dir)) == 1
    np.testing.assert_allclose(got["value"], want["value"], rtol=1e-15)
    np.testing.assert_allclose(got["grad"], want["grad"], rtol=1e-15)
    # A new process: nothing in memory, the file is read back (and not exported again).
    _programs._loaded.clear()
    stamp = _files(cache_dir)[0].stat().st_mtime_ns
    again = _poly(x, data, 3)
    np.testing.assert_allclose(again["grad"], want["grad"], rtol=1e-15)
    assert _files(cache_dir)[0].stat().st_mtime_ns == stamp
    # Another static argument or shape is another program.
    _poly(x, data, 2)
    _poly(np.ones(3), {"w": np.ones(3)}, 3)
    assert len(_files(cache_dir)) == 3


def test_unreadable_file_is_replaced(cache_dir):
    x = np.ones(4)
    _poly(x, {"w": np.ones(4)}, 2)
    (path,) = _files(cache_dir)
    path.write_bytes(b"not a program")
    _programs._loaded.clear()
    out = _poly(x, {"w": np.ones(4)}, 2)
    assert float(out["value"]) == 4.0
    assert path.read_bytes() != b"not a program"


def test_unexportable_output_falls_back(cache_dir):
    out = _boxed(np.ones(3))
    assert isinstance(out, _Box)
    np.testing.assert_array_equal(out.v, 2.0)
    assert _files(cache_dir) == []


def test_without_cache_dir_it_is_filter_jit(monkeypatch):
    monkeypatch.setattr(_programs, "_program_dir", lambda: None)
    out = _poly(np.ones(2), {"w": np.ones(2)}, 1)
    assert float(out["value"]) == 2.0


def _compiles():
    """A counter of XLA compilations (jax's compile events) from now on."""
    seen = {"n": 0}

    def on_event(event, seconds, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            seen["n"] += 1

    jax.monitoring.register_event_duration_secs_listener(on_event)
    return seen


def test_fast_compile_gives_the_same_answers(cache_dir):
    x = np.linspace(0.0, 1.0, 7)
    data = {"w": np.linspace(1.0, 2.0, 7)}
    want = eqx.filter_jit(_poly.__wrapped__)(x, data, 5)
    got = _poly_fast(x, data, 5)
    np.testing.assert_allclose(got["value"], want["value"], rtol=1e-14)
    np.testing.assert_allclose(got["grad"], want["grad"], rtol=1e-14)


def test_prefetch_compiles_once_and_the_call_uses_it(cache_dir):
    x, data = np.linspace(0.0, 1.0, 6), {"w": np.arange(6.0)}
    assert _poly.prefetch(np.zeros(6), {"w": np.zeros(6)}, 4)  # values do not matter
    assert not _poly.prefetch(np.ones(6), {"w": np.ones(6)}, 4)  # pending already
    (start,) = _prefetch._waiting
    assert not start.is_set()  # waits for this thread's next hand-off to XLA
    _poly(np.ones(2), {"w": np.ones(2)}, 1)  # another program: the hand-off
    assert start.is_set() and _prefetch._waiting == []
    _programs._pending[next(iter(_programs._pending))].result(timeout=120)
    seen = _compiles()
    got = _poly(x, data, 4)
    assert seen["n"] == 0  # the prefetch's executable, not a second compilation
    want = eqx.filter_jit(_poly.__wrapped__)(x, data, 4)
    np.testing.assert_allclose(got["grad"], want["grad"], rtol=1e-15)
    assert _programs._pending == {}
    assert not _poly.prefetch(x, data, 4)  # loaded already


def test_threads_needing_one_program_compile_it_once(cache_dir, monkeypatch):
    """Two threads that call one kept program at once (the map's row continuations with
    one corrector): one exports and compiles it, the other waits for it and computes with
    it; `bind` gives the same compiled program."""
    import threading

    monkeypatch.setattr(_programs, "_obtaining", {}, raising=False)
    x, data = np.linspace(0.0, 1.0, 7), {"w": np.arange(7.0)}
    want = eqx.filter_jit(_poly.__wrapped__)(x, data, 5)
    seen = _compiles()
    barrier = threading.Barrier(2)
    out = [None, None]

    def work(i):
        barrier.wait()
        out[i] = _poly(x, data, 5)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert seen["n"] == 1 and len(_files(cache_dir)) == 1
    for got in out:
        np.testing.assert_allclose(got["grad"], want["grad"], rtol=1e-15)
    run = _poly.bind(x, data, 5)
    assert seen["n"] == 1
    np.testing.assert_allclose(run(*jax.tree_util.tree_leaves((x, data)))["value"],
                               want["value"], rtol=1e-15)
    assert seen["n"] == 1


def test_call_before_any_hand_off_does_not_wait_forever(cache_dir):
    # The prefetch's only chance to start is the call itself, which must release it.
    x, data = np.ones(5), {"w": np.ones(5)}
    assert _poly.prefetch(x, data, 3)
    assert float(_poly(x, data, 3)["value"]) == 5.0


def test_prefetch_without_cache_dir_does_nothing(monkeypatch):
    monkeypatch.setattr(_programs, "_program_dir", lambda: None)
    assert not _poly.prefetch(np.ones(2), {"w": np.ones(2)}, 1)


def test_static_functions_of_bsfs_jax_are_named_others_are_not_kept():
    # A sweep's vector field is a static argument: a module-level function of bsfs_jax is
    # keyed by its name (its code is in the key's digest of the package), any other
    # function keeps its address in the text, so its programs are never kept (a user's
    # edited function must not find a stale program).
    from bsfs_jax.model import kernel_vector_field, vector_field

    def mine(t, y, args):
        return y

    x = np.ones(3)
    leaves, treedef = jax.tree_util.tree_flatten(((x,), {}))
    key = _programs._key(_poly.__wrapped__, ((vector_field, 2), {}), treedef, leaves)
    assert key is not None
    assert key == _programs._key(_poly.__wrapped__, ((vector_field, 2), {}), treedef, leaves)
    assert key != _programs._key(_poly.__wrapped__, ((kernel_vector_field, 2), {}), treedef,
                                 leaves)
    assert _programs._key(_poly.__wrapped__, ((mine, 2), {}), treedef, leaves) is None


def test_prefetch_compiles_only_after_a_foreground_compilation():
    """A prefetch's XLA compilation waits while one outside the prefetch thread is marked
    (`foreground_compile`): two compilations at once were slower than in turn."""
    import threading

    started = threading.Event()

    @jax.jit
    def f(x):
        return jnp.sin(x) * 3.0 + x

    class Lowered:  # a stand-in that records when its compile starts
        def compile(self):
            started.set()
            return f.lower(jnp.ones(3)).compile()

    with _prefetch.foreground_compile():
        fut = _prefetch.in_background(lambda: _prefetch.compile_in_background(Lowered()))
        assert not started.wait(0.5)  # held while the foreground compiles
        assert not fut.done()
    assert started.wait(30.0)
    fut.result(timeout=60.0)



@bsfs_jax.cached_jit(fast_compile=True, runs_long=True)
def _poly_long(x, data, power: int):
    return _poly.__wrapped__(x, data, power)


def test_a_long_running_program_gives_the_plain_programs_answers(cache_dir):
    """`runs_long` (XLA's newer CPU fusion emitters for the kept program): exported, then
    read back from its file, and plain, the same values as `filter_jit`."""
    x, data = jnp.linspace(0.0, 1.0, 5), {"w": jnp.arange(5.0)}
    want = eqx.filter_jit(_poly.__wrapped__)(x, data, 3)
    for read_back in (False, True):
        if read_back:
            _programs._loaded.clear()
        got = _poly_long(x, data, 3)
        np.testing.assert_allclose(got["value"], want["value"], rtol=1e-15)
        np.testing.assert_allclose(got["grad"], want["grad"], rtol=1e-15)
    plain = _poly_long.plain
    assert float(plain(x, data, 2)["value"]) == pytest.approx(float(jnp.sum(data["w"] * x**2)))
