"""Arrange the records of a `Problem` into per-speed arrays and map records to residual rows.

Within a speed the data residual holds, in order, the linear and first-order sine records
(R, H), the nonlinear sine records (S, H) and the lines of all FRF records (L,), each as all
real parts then all imaginary parts. `layout[i] = (group, kind, rows, selector)` gives
record i's group index, kind (0 linear or first-order, 1 nonlinear, 2 FRF), its residual
rows and how to pick its model values from the group's prediction.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np


def _sine_arrays(problem, idx, h):
    if not idx:
        return [np.zeros((0, h)), np.zeros((0, h), complex), np.zeros((0, h), complex),
                np.zeros((0, h, 2))]
    data = problem.data
    freq = np.stack([data[i].frequency_hz * data[i].harmonics for i in idx])
    force = np.stack([data[i].force for i in idx])
    acc = np.stack([data[i].acceleration for i in idx])
    # Errors in both channels: var(A - G F) = var(A) + |G|^2 var(F), with G the model's
    # transfer where the models were chosen (a weight only; not differentiated).
    g = np.stack([problem.transfer[i] for i in idx])
    var = (np.stack([data[i].acceleration_var for i in idx])
           + np.abs(g)[..., None] ** 2 * np.stack([data[i].force_var for i in idx]))
    # Harmonics near the anti-alias filter are left out (their phase is the filter's, not
    # the structure's): infinite std -> zero residual.
    std = np.where((freq <= problem.max_harmonic_hz)[..., None], np.sqrt(var), np.inf)
    return [freq, force, acc, std]


def _frf_arrays(problem, idx):
    if not idx:
        return [np.zeros(0), np.zeros(0, complex), np.zeros((0, 2))]
    data = problem.data
    freq = np.concatenate([np.asarray(data[i].frequency_hz, float) for i in idx])
    acc = np.concatenate([np.asarray(data[i].accelerance, complex) for i in idx])
    # Lines the linear FRF cannot model within the model-error bound: infinite std.
    std = np.sqrt(np.concatenate([
        np.where(np.asarray(problem.frf_left_out.get(i, False))[..., None], np.inf,
                 np.asarray(data[i].variance, float)) for i in idx]))
    return [freq, acc, std]


def build_groups(problem):
    from ._problem import _Group, is_frf

    data, models = problem.data, problem.models
    sines = [d for d in data if not is_frf(d)]
    h = sines[0].harmonics.size if sines else 1
    groups, layout, pos = [], {}, 0
    for gi, s in enumerate(problem.speeds):
        members = [[i for i, d in enumerate(data) if d.speed_rpm == s and models[i] in kinds]
                   for kinds in (("linear", "first-order"), ("nonlinear",), ("frf",))]
        first = np.asarray([models[i] == "first-order" for i in members[0]], bool)
        lf, lF, lA, lS = _sine_arrays(problem, members[0], h)
        nf, nF, nA, nS = _sine_arrays(problem, members[1], h)
        ff, fA, fS = _frf_arrays(problem, members[2])
        groups.append(_Group(jnp.asarray(lf), jnp.asarray(lF), jnp.asarray(lA), jnp.asarray(lS),
                             jnp.asarray(first),
                             jnp.asarray(nf[:, 0] if nf.size else np.zeros(0)),
                             jnp.asarray(nF), jnp.asarray(nA), jnp.asarray(nS),
                             jnp.asarray(ff), jnp.asarray(fA), jnp.asarray(fS)))
        for kind in (0, 1):
            count = len(members[kind])
            for j, i in enumerate(members[kind]):
                rows = np.concatenate([pos + j * h + np.arange(h),
                                       pos + count * h + j * h + np.arange(h)])
                layout[i] = (gi, kind, rows, j)
            pos += 2 * count * h
        total = ff.size
        start = 0
        for i in members[2]:
            n = np.asarray(data[i].frequency_hz).size
            rows = np.concatenate([pos + start + np.arange(n), pos + total + start + np.arange(n)])
            layout[i] = (gi, 2, rows, slice(start, start + n))
            start += n
        pos += 2 * total
    return groups, layout
