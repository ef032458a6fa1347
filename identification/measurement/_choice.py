"""Which measurement model each record gets, decided from its own noise.

A sine record gets the linearised FRF where its predicted error (`linearisation_error`, the
first harmonic-balance step from the linear steady state) is below `MODEL_ERROR` standard
errors in every usable harmonic; else the first-order model (linear + that step) where one
more step changes it by less than `MODEL_ERROR`; else the periodic orbit (harmonic balance). A
chirp's FRF lines whose predicted linear-model error exceeds `FRF_LINE_ERROR` are left out
(the FRF of a sweep has no steady-state nonlinear model). `Problem` makes the choice at the
prior and `fit` makes it again at the estimate, where decisions within a factor 2 of the
bound keep their previous value (`keep_marginal`).

The chirp rule is a screen, not a model of the sweep: the steady-state amplitude at each
line bounds the swept response from above, and a one-step prediction of how the kept
lines' remaining error shifts the estimates came out with the wrong sign against
noise-free replicates (so it is not reported). What the rule achieves is measured by the
coverage study (docs/COVERAGE.md).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import bsfs_jax

from ._harmonics import is_frf
from ._linear import chord_corrections, linearisation_error, receptance

# The bound on a model's predicted error, in standard errors of each entry. Per entry it is
# small against the noise; summed over many entries (a chirp's lines) a deterministic error
# can still shift an estimate by a larger fraction of its standard error: the coverage study
# (docs/COVERAGE.md) measures what remains.
MODEL_ERROR = 0.1
# The bound for a chirp's FRF lines, stricter: the lines next to the left-out resonance
# each carry a model error of one sign, and a hundred of them lean on the damping together.
# With the lines' bound at MODEL_ERROR the forecast's damping ratio came out 0.54 standard
# deviations low over 100 replicates of the preload-loss test (its estimate's standard
# deviation 0.24 %); at 0.03, 0.26; at 0.01, 0.14 +- 0.10, the model error that
# noise-free records show (0.12), with a standard deviation of 0.47 %
# (docs/COVERAGE.md, "The chirp's flank lines").
FRF_LINE_ERROR = 0.01


def line_bound(model_error: float) -> float:
    """The bound on a chirp line's predicted error that goes with `model_error` (the sine
    records' bound): `FRF_LINE_ERROR` at the default."""
    return model_error * FRF_LINE_ERROR / MODEL_ERROR

_receptance_jit = eqx.filter_jit(receptance)
_error_lines_jit = eqx.filter_jit(jax.vmap(linearisation_error, in_axes=(None, 0, 0)))
# FRF lines are screened in blocks of this many, by one compiled program per quantity called
# in a loop: a record of any line count reuses it, and no program or buffer grows with it.
LINE_BLOCK = 2048


def _blocks(fn, system, *arrays):
    """`fn(system, *blocks)` over `arrays` (n, ...) in blocks of `LINE_BLOCK` rows, the last
    padded with copies of its last row; the results (n, ...) as numpy."""
    n = arrays[0].shape[0]
    out = []
    for lo in range(0, max(n, 1), LINE_BLOCK):
        parts = []
        for x in arrays:
            b = x[lo:lo + LINE_BLOCK]
            if b.shape[0] == 0:
                b = np.zeros((1,) + x.shape[1:], x.dtype)
            parts.append(jnp.asarray(np.concatenate(
                [b, np.repeat(b[-1:], LINE_BLOCK - b.shape[0], axis=0)])))
        out.append(np.asarray(fn(system, *parts))[:min(LINE_BLOCK, n - lo)])
    return np.concatenate(out)[:n]


@bsfs_jax.cached_jit
def _sine_kernel(system, freq, harmonics, force, errors: bool):
    """One compiled call for all sine records of a speed: joint amplitudes of the linear
    response, the model's transfer (accelerance) per harmonic, and where `errors` the first
    and second chord steps of `linearisation_error`."""
    fk = freq[:, None] * harmonics[None, :]  # (R, H)
    h = receptance(system, fk.reshape(-1)).reshape(*fk.shape, 3)
    x = h * force[..., None]
    u_bearing = jnp.sum(jnp.abs(x[..., 0]), axis=1)
    u_nut = jnp.sum(jnp.abs(x[..., 2] - x[..., 1]), axis=1)
    transfer = -((2.0 * jnp.pi * fk) ** 2) * h[..., 2]
    if not errors:
        return u_bearing, u_nut, transfer, None, None
    both = jax.vmap(lambda f, fc: chord_corrections(system, f, fc, 2))(freq, force)
    return u_bearing, u_nut, transfer, both[:, 0], both[:, 1]


def _preload_deformations(system):
    return (float(system.nut.a - system.nut.a0 - system.nut.offset),
            float(system.bearing.a - system.bearing.a0 - system.bearing.offset))


def screen_sines(system, sines, max_harmonic_hz=np.inf, errors: bool = True):
    """For sine records at one speed (`HarmonicData`, same harmonics): (amplitude ratios,
    model errors, transfers).

    - ratio: the largest joint deformation amplitude of the linear response over its
      preload deformation (the nonlinearity error grows about as its square);
    - errors (None unless `errors`): (linear, first-order), the largest |error| / std over
      the Re and Im parts of the usable harmonics of the linearised model (its first-order
      correction, `linearisation_error`) and of the first-order model (one more chord step
      changes it by that much); std from both channels, var(A) + |G|^2 var(F);
    - transfer (H,): the model's accelerance G at the harmonics (the weights' G).
    """
    if not sines:
        return [], [], []
    # The records padded to a power of two (at least 4) by repeating the last: one
    # compiled kernel for every plan and record count (`plan-test` compiled it for six
    # counts), each row independent of the others.
    n = len(sines)
    rows = list(range(n)) + [n - 1] * (max(4, 1 << (n - 1).bit_length()) - n)
    out = _sine_kernel(system, jnp.asarray([sines[i].frequency_hz for i in rows], float),
                       jnp.asarray(sines[0].harmonics, float),
                       jnp.asarray(np.stack([sines[i].force for i in rows])), errors)
    out = [None if a is None else np.asarray(a)[:n] for a in out]
    u_b, u_n, g = out[:3]
    d_nut, d_bearing = _preload_deformations(system)
    ratios = [float(max(a / d_nut, b / d_bearing)) for a, b in zip(u_n, u_b)]
    z = [None] * len(sines)
    if errors:
        one, two = np.asarray(out[3]), np.asarray(out[4])
        for i, d in enumerate(sines):
            var = d.acceleration_var + np.abs(g[i])[:, None] ** 2 * d.force_var
            usable = d.frequency_hz * d.harmonics <= max_harmonic_hz
            z[i] = tuple(float(np.max(np.where(usable, error_in_std(e, var), 0.0)))
                         for e in (one[i], two[i] - one[i]))
    return ratios, z, list(g)


def frf_amplitude_ratio(system, data) -> float:
    """As `screen_sines`' ratio for an FRF record, with the force level in its header taken
    as the amplitude at every line (0 when the file does not give it)."""
    freq = np.asarray(data.frequency_hz)
    force = np.full(freq.shape, float(data.force_amplitude_n or 0.0))
    x = _blocks(_receptance_jit, system, freq) * force[:, None]
    d_nut, d_bearing = _preload_deformations(system)
    return float(max(np.max(np.abs(x[:, 2] - x[:, 1])) / d_nut,
                     np.max(np.abs(x[:, 0])) / d_bearing))


def error_in_std(err, var):
    """|err| in standard errors per entry: the larger of |Re| and |Im| over their stds
    (`var` (..., 2): the variances of Re and Im); inf where undefined."""
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.maximum(np.abs(err.real) / np.sqrt(var[..., 0]),
                       np.abs(err.imag) / np.sqrt(var[..., 1]))
    return np.where(np.isnan(z), np.inf, z)


def chirp_line_z(system, data):
    """Predicted linear-model error per line of an FRF record, in standard errors.

    Chirp: at the record's force level as a steady-state amplitude (an upper bound for a
    sweep). Other FRF records (random, hammer, unknown level): zeros, not checked (the level
    per line is not known).
    """
    freq = np.asarray(data.frequency_hz, float)
    if data.excitation != "chirp" or not data.force_amplitude_n:
        return np.zeros(freq.shape)
    force = np.full((freq.size, 1), float(data.force_amplitude_n), complex)
    err = _blocks(_error_lines_jit, system, freq, force)[:, 0]
    z = error_in_std(err, np.asarray(data.variance, float))
    return np.where(np.isfinite(z), z, 0.0)


def screen(data, speeds, systems, max_harmonic_hz, errors: bool, lines: bool):
    """Per record (lists in data order): amplitude ratios, predicted model errors (None where
    not computed: sine records unless `errors`, FRF records unless `lines`); and {record:
    model transfer at its harmonics} for the sine records (the weights' G)."""
    n = len(data)
    ratios, z, transfer = [0.0] * n, [None] * n, {}
    for s in speeds:
        idx = [i for i, d in enumerate(data) if d.speed_rpm == s and not is_frf(d)]
        r_s, z_s, g_s = screen_sines(systems[s], [data[i] for i in idx], max_harmonic_hz,
                                     errors)
        for j, i in enumerate(idx):
            ratios[i], z[i], transfer[i] = r_s[j], z_s[j], g_s[j]
    for i, d in enumerate(data):
        if is_frf(d):
            ratios[i] = frf_amplitude_ratio(systems[d.speed_rpm], d)
            if lines:
                z[i] = chirp_line_z(systems[d.speed_rpm], d)
    return ratios, z, transfer


def keep_marginal(problem, previous, bound: float):
    """(models, frf_left_out) of `problem`, except that where a decision changed from
    `previous` but its predicted error lies within a factor 2 of `bound`, `previous`'s
    decision is kept (see `Problem.rechosen`)."""
    order = ("linear", "first-order", "nonlinear")
    models, left_out = list(problem.models), {}
    for i, (new, old) in enumerate(zip(problem.models, previous.models)):
        if new != old and new in order and old in order:
            lo, hi = sorted((order.index(new), order.index(old)))
            z = problem.linearisation_z[i]
            if all(marginal_mask(z[k], bound) for k in range(lo, hi)):  # every bound crossed
                models[i] = old
    for i, z in enumerate(problem.linearisation_z):
        if is_frf(problem.data[i]) and z is not None:
            new = problem.frf_left_out.get(i, np.zeros(z.shape, bool))
            old = previous.frf_left_out.get(i, np.zeros(z.shape, bool))
            keep = np.where((new != old) & marginal_mask(z, line_bound(bound)), old, new)
            if keep.any():
                left_out[i] = keep
    return models, left_out


def marginal_mask(z, bound):
    """Where a predicted error is within a factor 2 of the bound (elementwise)."""
    return (np.asarray(z) >= bound / 2) & (np.asarray(z) <= 2 * bound)


def same_choice(a, b) -> bool:
    """Whether problems `a` and `b` use the same model per record and leave out the same
    FRF lines."""
    return (a.models == b.models and a.frf_left_out.keys() == b.frf_left_out.keys()
            and all(np.array_equal(v, b.frf_left_out[k]) for k, v in a.frf_left_out.items()))
