"""Which measurement model each record gets, decided from its own noise.

A sine record gets the linearised FRF where its predicted error (`linearisation_error`, the
first harmonic-balance step from the linear steady state) is below `MODEL_ERROR` standard
errors in every usable harmonic; else the first-order model (linear + that step) where one
more step changes it by less than `MODEL_ERROR`; else the periodic orbit (shooting). A
chirp's FRF lines whose predicted linear-model error exceeds `MODEL_ERROR` are left out
(the FRF of a sweep has no steady-state nonlinear model). `Problem` makes the choice at the
prior and `fit` makes it again at the estimate.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._measurement import linear_acceleration, linearisation_error, receptance

# The bound on a model's predicted error, in standard errors of each entry. Per entry it is
# small against the noise; summed over many entries (a chirp's lines) a deterministic error
# can still shift an estimate by a larger fraction of its standard error: the coverage study
# (docs/COVERAGE.md) measures what remains.
MODEL_ERROR = 0.1

_linear_jit = eqx.filter_jit(linear_acceleration)
_receptance_jit = eqx.filter_jit(receptance)
_error_jit = eqx.filter_jit(lambda system, f, fc: (linearisation_error(system, f, fc),
                                                  linearisation_error(system, f, fc, steps=2)))
_error_lines_jit = eqx.filter_jit(jax.vmap(linearisation_error, in_axes=(None, 0, 0)))


def is_frf(d) -> bool:
    return hasattr(d, "accelerance")


def joint_amplitude_ratio(system, data) -> float:
    """Largest joint deformation amplitude / preload deformation, linear prediction (numpy).

    The nonlinearity error of the linear model grows about as this ratio squared; at the
    paper's 100 N and 100-150 Hz it is 0.04-0.05 (error ~1e-5, far below the noise). For an
    FRF record the force level in its header is taken as the amplitude at every line (0
    when the file does not give it).
    """
    if is_frf(data):
        freq = np.asarray(data.frequency_hz)
        force = np.full(freq.shape, float(data.force_amplitude_n or 0.0))
        h = np.asarray(_receptance_jit(system, jnp.asarray(freq)))
        x = h * force[:, None]
        u_bearing, u_nut = np.max(np.abs(x[:, 0])), np.max(np.abs(x[:, 2] - x[:, 1]))
    else:
        h = np.asarray(_receptance_jit(system, jnp.asarray(data.frequency_hz * data.harmonics)))
        x = h * data.force[:, None]
        u_bearing = np.sum(np.abs(x[:, 0]))
        u_nut = np.sum(np.abs(x[:, 2] - x[:, 1]))
    d_nut = float(system.nut.a - system.nut.a0 - system.nut.offset)
    d_bearing = float(system.bearing.a - system.bearing.a0 - system.bearing.offset)
    return float(max(u_nut / d_nut, u_bearing / d_bearing))


def _z(err, var):
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.maximum(np.abs(err.real) / np.sqrt(var[..., 0]),
                       np.abs(err.imag) / np.sqrt(var[..., 1]))
    return np.where(np.isnan(z), np.inf, z)


def linearisation_z(system, data, max_harmonic_hz=np.inf):
    """Predicted model errors in standard errors (numpy, >= 0), at `system`.

    Sine record: (linear, first-order), the largest |error| / std over the Re and Im parts
    of its usable harmonics of the linearised model (its first-order correction,
    `linearisation_error`) and of the first-order model (one more chord step changes it by
    that much). Chirp FRF record: the linear model's per line, at the record's force level
    as a steady-state amplitude (an upper bound for a sweep). Other FRF records (random,
    hammer, unknown level): zeros, not checked (the level per line is not known).
    """
    if is_frf(data):
        freq = np.asarray(data.frequency_hz, float)
        if data.excitation != "chirp" or not data.force_amplitude_n:
            return np.zeros(freq.shape)
        force = np.full((freq.size, 1), float(data.force_amplitude_n), complex)
        err = np.asarray(_error_lines_jit(system, jnp.asarray(freq), jnp.asarray(force)))[:, 0]
        z = _z(err, np.asarray(data.variance, float))
        return np.where(np.isfinite(z), z, 0.0)
    freq = data.frequency_hz * data.harmonics
    one, two = map(np.asarray, _error_jit(system, float(data.frequency_hz),
                                          jnp.asarray(data.force)))
    g = np.asarray(_linear_jit(system, jnp.asarray(freq), jnp.ones(freq.shape, complex)))
    var = data.acceleration_var + np.abs(g)[:, None] ** 2 * data.force_var
    usable = freq <= max_harmonic_hz
    return tuple(float(np.max(np.where(usable, _z(e, var), 0.0))) for e in (one, two - one))
