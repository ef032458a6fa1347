"""The fit's optimistix solve: compiled once per layout, and the same optimum as MINPACK.

- One compilation: over 3 starts, 2 held-parameter variants (the profile likelihood) and 2
  replicates (new data of the same layout), jax's backend-compile events name the solve's
  program exactly once.
- Cross-check: MINPACK's Levenberg-Marquardt (scipy, `tests/minpack_fit.py`) on the same
  compiled residual and Jacobian reaches the same optimum on the paper's test and on the
  preload-loss set (sines and a chirp): every parameter within 1e-3 of its standard error,
  the cost within 1e-8 relative.
"""

import dataclasses

import jax
import numpy as np
import pytest
from minpack_fit import levenberg_marquardt

import bsfs_jax
import identification as idn
from identification.fitting._fit import full_used_mask, no_information_std
from identification.fitting._solve import SolveOptions, solve
from identification.intervals._profile import held_costs


@pytest.fixture(scope="module")
def paper_data():
    return [idn.measurement_data(r) for r in
            idn.load_records(idn.bundled_records("paper-test"))]


class _CompileCounter:
    def __init__(self, name):
        self.name, self.count = name, 0

    def __call__(self, event, duration, **kw):
        if event == "/jax/core/compile/backend_compile_duration" and \
                self.name in str(kw.get("fun_name", "")):
            self.count += 1


def _replicate(data, seed):
    """The same records with new noise of their own standard errors (same layout)."""
    rng = np.random.default_rng(seed)
    out = []
    for d in data:
        sd = np.sqrt(d.acceleration_var)
        noise = sd[:, 0] * rng.normal(size=sd.shape[0]) + 1j * sd[:, 1] * rng.normal(
            size=sd.shape[0])
        out.append(dataclasses.replace(d, acceleration=d.acceleration + noise))
    return out


@pytest.fixture
def no_persistent_cache():
    """A cache hit is not a compile event: start from empty in-process caches (another test
    in this process may have compiled the same layout) and without the persistent cache
    (CI shares one between test files), so that real compilations are counted."""
    from bsfs_jax import _programs

    was = jax.config.jax_enable_compilation_cache
    jax.config.update("jax_enable_compilation_cache", False)
    jax.clear_caches()
    _programs._loaded.clear()  # programs kept by `cached_jit` are compiled again too
    yield
    jax.config.update("jax_enable_compilation_cache", was)


def test_the_solve_compiles_once_for_starts_held_variants_and_replicates(paper_data,
                                                                         no_persistent_cache):
    counter = _CompileCounter("_solve_lanes")
    jax.monitoring.register_event_duration_secs_listener(counter)
    # A prior no other test uses, so that nothing is cached in this process already.
    prior = bsfs_jax.preset().replace("damping.screw_n_s_per_m", 812.5)
    pb = idn.Problem(paper_data, prior)
    res = idn.fit(pb, starts=3)  # 3 starts (and the model choice confirmed at the estimate)
    assert res.converged and len(res.starts) == 3
    i = pb.names.index("screw_k")
    thetas, costs = held_costs(pb, [res.theta, res.theta], [i, i],
                               [res.theta[i] - 0.05, res.theta[i] + 0.05])  # 2 variants
    assert np.all(costs > 2 * res.cost) and np.allclose(thetas[:, i], res.theta[i] + [-.05, .05])
    replicates = []
    for seed in (1, 2):  # 2 replicates: new data, new Problem, same layout
        rep = idn.fit(idn.Problem(_replicate(paper_data, seed), prior), starts=1)
        assert rep.converged
        replicates.append(rep.cost)
    assert replicates[0] != replicates[1] != res.cost
    assert counter.count == 1, f"the solve compiled {counter.count} times"


def _cross_check(pb):
    """Both optimisers from the prior with a tight step test; compare the optima."""
    rows = full_used_mask(pb)
    ours = solve(np.zeros((1, pb.n_params)), True, pb.fit_data, pb.structure,
                 SolveOptions(step_tol=1e-6))
    mp = levenberg_marquardt(pb.rj, np.zeros(pb.n_params), max_steps=400, tol=1e-6, rows=rows,
                             max_std=no_information_std(pb))
    assert mp.converged, mp.reason
    theta = ours["theta"][0]
    r, j = pb.rj(theta)
    res = idn.FitResult(pb, theta, pb.values(theta), float(ours["cost"][0]), r, j, [], True,
                        True, 0.0, int(ours["steps"][0]), 0.0)
    std = idn.uncertainty(res).scaled_std
    assert np.all(np.abs(theta - mp.theta) < 1e-3 * std), (theta - mp.theta) / std
    assert abs(ours["cost"][0] - mp.cost) <= 1e-8 * mp.cost
    return int(ours["steps"][0]), mp.evaluations


def test_same_optimum_as_minpack_on_the_paper_test(paper_data):
    _cross_check(idn.Problem(paper_data, bsfs_jax.preset()))


def test_same_optimum_as_minpack_on_the_preload_loss_set():
    data = [idn.measurement_data(r) for r in
            idn.load_records(idn.bundled_records("preload-loss"))]
    assert any(hasattr(d, "accelerance") for d in data)  # the chirp's FRF is in
    _cross_check(idn.Problem(data, bsfs_jax.preset(), idn.PRELOAD_FIT))


@pytest.mark.parametrize("z, gated", [(0.5, False), (2.0, True), (float("nan"), True)])
def test_the_truncation_gate_names_the_record_and_its_kind(z, gated):
    """A record whose orbit model is off by more than the gate at the estimate (or whose
    32-harmonic check failed: nan) makes the fit not converged, with a kind for programs."""
    from identification.fitting._check import TRUNCATION_GATE, gate_truncation
    from identification.fitting._fit import FitResult

    res = FitResult(None, np.zeros(1), np.ones(1), 1.0, np.zeros(2), np.zeros((2, 1)), [],
                    True, True, 0.0, 1, 0.0)
    gate_truncation(res, {1: dict(orbit_truncation_error_std=z)}, ["a", "b"])
    assert res.converged is (not gated)
    assert res.model_issue_kinds == (["truncation"] if gated else [])
    if gated:
        assert "'b'" in res.model_issues[0] and f"{TRUNCATION_GATE:g}" in res.model_issues[0]


@pytest.mark.parametrize("scales, gated", [
    ((1, 1, 30, 1, 1), [2]),       # one record 30x its noise, the others at it: gated
    ((30, 25, 30, 35, 30), []),    # model error spread over every record: widened instead
    ((1, 1, 5, 1, 1), []),         # 5x its noise: under the gate
    ((1, 30), []),                 # two records: nothing to compare a misfit with
])
def test_a_record_the_model_does_not_explain_makes_the_fit_not_converged(scales, gated):
    """Widening the intervals by the noise scale assumes the model error is spread over
    the records; where one record carries it, it sets the estimate (drive 267 of the
    preload robustness study), and the fit says it is not converged, naming the record."""
    import types

    from identification.fitting._fit import FitResult
    from identification.fitting._misfit import gate_record_misfit

    rng = np.random.default_rng(1)
    n = 40
    names = [f"rec{k}" for k in range(len(scales))]
    residual = np.concatenate([s * rng.standard_normal(n) for s in scales] + [np.zeros(2)])
    used = np.ones(n * len(scales), bool)
    problem = types.SimpleNamespace(
        data=[types.SimpleNamespace(name=nm) for nm in names], used_mask=lambda: used,
        record_slices=lambda: [slice(k * n, (k + 1) * n) for k in range(len(scales))])
    problem.record_residuals = lambda r: idn.Problem.record_residuals(problem, r)
    res = FitResult(problem, np.zeros(2), np.ones(2), 1.0, residual,
                    np.zeros((residual.size, 2)), [], True, True, 0.0, 1, 0.0)
    gate_record_misfit(res)
    assert res.converged is (not gated)
    assert res.model_issue_kinds == ["record_misfit"] * len(gated)
    for k, text in zip(gated, res.model_issues):
        assert f"'{names[k]}'" in text and "identify without it" in text


def test_other_line_counts_and_bands_reuse_the_compiled_programs(no_persistent_cache):
    """Each chirp's usable band, hence its FRF line count, differs from record to record,
    and each identification's FRC band starts at its own f1. Both compiled anew per record
    set (the forecast coverage study's process grew by about 0.05 GB per replicate): the
    line counts are now padded to a bucket, and the band's start is traced."""
    import types

    import jax.numpy as jnp

    from bsfs_jax.design._orbit import _linear_start
    from bsfs_jax.machine import bsfs_family
    from identification.measurement import _choice
    from identification.measurement._linear import receptance

    system = bsfs_jax.build_system(bsfs_jax.preset())
    counter = _CompileCounter("")
    jax.monitoring.register_event_duration_secs_listener(counter)
    try:
        ratios, counts = [], []
        for n in (1100, 1200):  # one bucket (1536 lines)
            f = np.linspace(100.0, 2500.0, n)
            ratios.append(_choice.frf_amplitude_ratio(
                system, types.SimpleNamespace(frequency_hz=f, force_amplitude_n=5.0)))
            counts.append(counter.count)
        assert counts[1] == counts[0]  # the second line count compiled nothing
        family = bsfs_family(bsfs_jax.preset(), 100.0)
        _linear_start(family, jnp.asarray(900.0, float))
        second = counter.count
        _linear_start(family, jnp.asarray(950.0, float))
        assert counter.count == second
    finally:
        jax._src.monitoring.unregister_event_duration_listener(counter)
    f = np.linspace(100.0, 2500.0, 1100)
    x = np.asarray(receptance(system, jnp.asarray(f)))  # unpadded, for the value
    d_nut, d_bearing = _choice._preload_deformations(system)
    expected = max(np.max(np.abs(5.0 * (x[:, 2] - x[:, 1]))) / d_nut,
                   np.max(np.abs(5.0 * x[:, 0])) / d_bearing)
    assert abs(ratios[0] - expected) <= 1e-12 * expected
