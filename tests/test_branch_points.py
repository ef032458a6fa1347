"""Exact derivatives of the FRC's folds and peak frequency (`design._orbit`), checked against
finite differences that re-run the continuation and locate the points again each time."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import bsfs_jax
from bsfs_jax.design import OrbitSettings, locate_frc_peak, with_values
from bsfs_jax.design.building import (
    fold_frequency_value,
    frc_peak_frequency_value,
    frc_peak_value,
    frc_point_values,
    point_hint,
)
from bsfs_jax.solvers import ImplicitForward

jax.config.update("jax_enable_x64", True)

NAMES = ("nut.preload_n", "damping.nut_n_s_per_m")
# 100 N on the default preset: the joints lose contact at the resonance and the curve folds
# between about 1118.7 and 1120.2 Hz (tests/test_design.py); harmonic balance meets 1e-4
# there with 32 harmonics.
FOLDED = OrbitSettings(frc_band=(0.975, 0.99), frc_method="hb", frc_tol=1e-4)
REL_STEP = 1e-3


@pytest.fixture(scope="module")
def base():
    p = bsfs_jax.preset()
    return p, jnp.array([p.get(n) for n in NAMES])


def _located(p, theta, force, settings):
    return locate_frc_peak(with_values(p, NAMES, theta), force, settings)


def _central(fn, theta):
    out = []
    for i in range(theta.shape[0]):
        d = REL_STEP * theta[i]
        out.append((fn(theta.at[i].add(d)) - fn(theta.at[i].add(-d))) / (2 * d))
    return np.stack(out, axis=-1)


def test_fold_frequencies_have_exact_gradients(base):
    p, theta = base
    hint, branch = _located(p, theta, 100.0, FOLDED)
    folds = [b for b in branch.bifurcations if b.kind == "fold"]
    assert len(folds) == 2 and all(b.point is not None for b in folds)
    hints = [point_hint(b.point, branch) for b in folds]

    def value(th, h):
        return fold_frequency_value(with_values(p, NAMES, th), 100.0, h)

    rev = np.stack([jax.grad(value)(theta, h) for h in hints])
    fwd = np.stack([jax.jacfwd(lambda th, h=h: fold_frequency_value(
        with_values(p, NAMES, th), 100.0, h, ImplicitForward()))(theta) for h in hints])
    np.testing.assert_allclose(fwd, rev, rtol=1e-8)
    assert [float(value(theta, h)) for h in hints] == pytest.approx([b.p for b in folds],
                                                                     rel=1e-12)
    # The forecast's one program for the peak amplitude and the folds (vmapped over the
    # stacked hints, forward mode) gives the same derivatives.
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), hint, *hints)
    both = np.asarray(jax.vmap(lambda h: jax.jacfwd(lambda th: frc_point_values(
        with_values(p, NAMES, th), 100.0, h, ImplicitForward()))(theta))(stacked))
    np.testing.assert_allclose(both[1:, 1], rev, rtol=1e-8)
    amp = jax.grad(lambda th: frc_peak_value(with_values(p, NAMES, th), 100.0, hint))(theta)
    np.testing.assert_allclose(both[0, 0], amp, rtol=1e-8)
    assert np.all(np.abs(amp) > 0)

    def fold_ps(th):
        br = _located(p, th, 100.0, FOLDED)[1]
        return np.array([b.p for b in br.bifurcations if b.kind == "fold"])

    fd = _central(fold_ps, theta)
    # Both derivatives are far from zero and of opposite signs for the damping (it closes
    # the fold), so a sign or factor error could not pass.
    np.testing.assert_allclose(rev, fd, rtol=2e-3)


def test_peak_frequency_has_an_exact_gradient(base):
    """30 N, no contact loss: the augmented system's second derivatives are smooth."""
    p, theta = base
    settings = OrbitSettings(frc_method="hb")
    hint, branch = _located(p, theta, 30.0, settings)
    assert not branch.bifurcations

    def value(th):
        return frc_peak_frequency_value(with_values(p, NAMES, th), 30.0, hint)

    assert float(value(theta)) == pytest.approx(branch.peak.p, rel=1e-12)
    grad = np.asarray(jax.jacfwd(value)(theta))
    fd = _central(lambda th: float(_located(p, th, 30.0, settings)[0].frequency_hz), theta)
    np.testing.assert_allclose(grad, fd, rtol=1e-4)
    assert np.all(np.abs(grad) > 0)
