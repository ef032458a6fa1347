"""The first-order (weakly nonlinear) measurement model and the model-error rule.

`linearisation_error` is harmonic balance by the chord method from the linear steady state;
its first step is the first-order model and the predicted error of the linear one. Checked
against the periodic orbit from the shooting engine (independent: time integration), and
the rule that picks a model per record against what it should pick on the bundled
preload-loss records.
"""

import jax.numpy as jnp
import numpy as np
import pytest

import bsfs_jax
import identification as idn
from identification.measurement._choice import FRF_LINE_ERROR
from identification.measurement._linear import (
    chord_corrections,
    linear_acceleration,
    linearisation_error,
)
from identification.measurement._orbit_model import nonlinear_acceleration


@pytest.fixture(scope="module")
def worn_system():
    p = bsfs_jax.load_params(idn.DATA_DIR / "worn.toml").replace("thermal.speed_rpm", 2000.0)
    return bsfs_jax.build_system(p)


@pytest.mark.parametrize("frequency, force", [(700.0, 100.0), (1117.0, 5.0)])
def test_chord_harmonic_balance_converges_to_the_periodic_orbit(worn_system, frequency,
                                                                force):
    fc = jnp.asarray([force, 0.04 * force, 0.02 * force], complex)
    lin = linear_acceleration(worn_system, frequency * jnp.arange(1, 4), fc)
    orbit, ok = nonlinear_acceleration(worn_system, frequency, fc)
    assert bool(ok)
    exact = np.asarray(orbit - lin)[0]
    one = np.asarray(linearisation_error(worn_system, frequency, fc))[0]
    five = np.asarray(linearisation_error(worn_system, frequency, fc, steps=5))[0]
    two = np.asarray(linearisation_error(worn_system, frequency, fc, steps=2))[0]
    # The nonlinearity is a measurable part of the response (not a round-off test) ...
    assert abs(exact) > 2e-5 * abs(np.asarray(lin)[0])
    # ... first order gets it to a few per cent, the iteration to the orbit's accuracy,
    # and one more step estimates the first step's error.
    assert abs(one - exact) < 0.05 * abs(exact)
    assert abs(five - exact) < 1e-3 * abs(exact)
    assert 0.3 < abs(two - one) / abs(one - exact) < 3.0


def _second_order_first_step(system, frequency, fc, samples=64):
    """The first chord step of harmonic balance in displacements, harmonics 1..H and no
    mean, written out here (numpy on the model's restoring forces): what identification
    computed before it used the orbit engine's residual."""
    from bsfs_jax.machine import tangent_matrices
    from bsfs_jax.model import restoring_forces

    k_mat, c_mat, m = (np.asarray(a) for a in tangent_matrices(system))
    h = len(fc)
    w = 2 * np.pi * frequency * np.arange(1, h + 1)
    dyn = k_mat[None] - w[:, None, None] ** 2 * np.diag(m)[None] + 1j * w[:, None, None] * c_mat
    rhs = np.zeros((h, 3), complex)
    rhs[:, 2] = fc
    x_lin = np.linalg.solve(dyn, rhs[..., None])[..., 0]
    phase = np.exp(1j * np.outer(2 * np.pi * np.arange(samples) / samples, np.arange(1, h + 1)))
    xs, vs = np.real(phase @ x_lin), np.real(phase @ (1j * w[:, None] * x_lin))
    f = np.asarray(restoring_forces(system, jnp.asarray(xs), jnp.asarray(vs)))
    r = (2.0 / samples) * (np.conj(phase).T @ f) - w[:, None] ** 2 * x_lin * m - rhs
    return -(w**2) * (-np.linalg.solve(dyn, r[..., None])[..., 0][:, 2])


@pytest.mark.parametrize("frequency, force", [(700.0, 100.0), (1117.0, 5.0), (150.0, 100.0)])
def test_the_first_order_model_is_the_displacement_chord_step(worn_system, frequency, force):
    """Identification's first-order correction runs on the orbit engine's AFT residual
    (`HarmonicBalance.chord`, states and the mean); its first step is the textbook
    displacement chord step (the first-order model is unchanged), and the mean shift it
    adds moves the second step by far less than the step itself."""
    fc = np.asarray([force, 0.04 * force - 0.01j * force, 0.02j * force], complex)
    steps = np.asarray(chord_corrections(worn_system, frequency, jnp.asarray(fc), 2))
    ref = _second_order_first_step(worn_system, frequency, fc)
    assert np.max(np.abs(steps[0] - ref)) < 1e-7 * np.max(np.abs(ref))
    assert np.max(np.abs(steps[1] - steps[0])) < 0.05 * np.max(np.abs(steps[0]))


@pytest.fixture(scope="module")
def preload_problem():
    data = [idn.measurement_data(r) for r in
            idn.load_records(idn.bundled_records("preload-loss"))]
    return idn.Problem(data, bsfs_jax.preset(), idn.PRELOAD_FIT)


def test_model_rule_on_the_preload_loss_records(preload_problem):
    pb = preload_problem
    models = {d.name: m for d, m in zip(pb.data, pb.models)}
    # The 700 Hz / 100 N sine is the one whose linear-model error exceeds 0.1 standard
    # errors (COVERAGE.md's diagnosis); its first-order correction is good enough.
    assert models["sine_0700hz_100n"] == "first-order"
    assert [m for n, m in models.items() if n.startswith("sine") and "0700" not in n] == [
        "linear"] * 4
    for d, z, m in zip(pb.data, pb.linearisation_z, pb.models):
        if m == "linear":
            assert z[0] <= idn.MODEL_ERROR
        if m == "first-order":
            assert z[0] > idn.MODEL_ERROR >= z[1]
    # The 5 N chirp: the lines at the first resonance (about 1140 Hz at the prior) are
    # left out, and only those (their predicted error above `FRF_LINE_ERROR`): they carry
    # no weight in the residual.
    (i, mask), = pb.frf_left_out.items()
    f = np.asarray(pb.data[i].frequency_hz)[mask]
    assert 1050 < f.min() and f.max() < 1250 and mask.sum() < 0.1 * mask.size
    z = np.asarray(pb.linearisation_z[i])
    assert np.all(z[mask] > FRF_LINE_ERROR) and np.all(z[~mask] <= FRF_LINE_ERROR)
    rows = pb.record_slices()[i]
    used = pb.used_mask()[rows]
    assert used.sum() == 2 * (mask.size - mask.sum())


def test_first_order_jacobian_matches_finite_differences(preload_problem):
    pb = preload_problem
    theta = np.array([0.02, -0.01, 0.05, 0.0, -0.03])
    r, jac = pb.rj(theta)
    rows = pb.record_slices()[[d.name for d in pb.data].index("sine_0700hz_100n")]
    # eps 1e-4: the residual (~300 here) carries round-off of ~1e-10, which a smaller step
    # amplifies; the truncation error at 1e-4 is ~1e-8 of the column's scale.
    eps = 1e-4
    fd = np.stack([(pb.rj(theta + eps * e)[0] - pb.rj(theta - eps * e)[0]) / (2 * eps)
                   for e in np.eye(theta.size)], axis=1)
    scale = np.max(np.abs(jac[rows]), axis=0)
    np.testing.assert_allclose(jac[rows] / scale, fd[rows] / scale, atol=1e-6)


def test_forced_linear_model_keeps_every_chirp_line():
    rec = idn.load_records(idn.bundled_records("preload-loss"))
    data = [d for d in map(idn.measurement_data, rec) if hasattr(d, "accelerance")]
    pb = idn.Problem(data, bsfs_jax.preset(), idn.PRELOAD_FIT, model="linear")
    # every line of every record is used (rows beyond the records are the layout's padding)
    assert pb.frf_left_out == {} and pb.used_mask()[np.concatenate(pb.record_slices())].all()
