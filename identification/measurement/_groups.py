"""The fit's data as traced arrays of a fixed layout, and where each record's rows lie.

Everything that varies between fits of the same kind of test (measured harmonics and lines,
their noise weights, which model each sine record uses, the prior parameter set, prior means
and widths, the spindle speeds) is an array in `FitData`; only the *structure* (which
parameter keys are fitted, for which speed, in log or offset form) is static (`Structure`).
Record counts are padded to size classes (`size_class`; a group's sine records to at least
`MIN_SINE_ROWS`): a padded sine record or FRF line
has an infinite standard error, so its residual and Jacobian rows are zero. So one compiled
program serves every start, held-parameter variant, model-choice iteration and replicate of
a layout (see `_model.py` and `_solve.py`).

Within a speed group the data residual holds the sine records' harmonics (R, H) as all real
parts then all imaginary parts, then the FRF lines (L,) likewise; the prior's p entries
follow the last group (zero where a parameter has no prior). `layout[i] = (group, kind,
rows, selector)`: record i's group, kind (0 sine, 1 FRF), residual rows and position in its
group's prediction (`predict`'s pair, indexed by kind).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import numpy as np

from ._orbit_model import ORBIT_HARMONICS

# A padded sine record sits at this (harmless) frequency with zero force.
_PAD_FREQUENCY_HZ = 100.0


def size_class(n: int) -> int:
    """Padded count: 0, or the next power of two (records, orbit slots and FRF lines)."""
    return 0 if n <= 0 else 1 << (int(n) - 1).bit_length()


#: The fewest sine rows of a speed group that has any: a fit of one to four sine records
#: then has one layout (a padded row costs one linear response per harmonic), so one
#: compiled solve serves them all (orbit slots, each an orbit solved, stay 1, 2, 4, ...).
MIN_SINE_ROWS = 4


def sine_rows(n: int) -> int:
    """Padded count of a group's sine records: 0, or `size_class` but at least
    `MIN_SINE_ROWS`."""
    return 0 if n <= 0 else max(MIN_SINE_ROWS, size_class(n))


@dataclasses.dataclass(frozen=True)
class Structure:
    """The static part of a fit problem (hashable: the compiled programs' cache key)."""

    keys: tuple  # vocabulary key of each fitted parameter
    groups: tuple  # speed-group index of each parameter (-1: shared by every speed)
    log: tuple  # bool per parameter: theta = ln(value / prior), else value - prior [um]
    n_groups: int
    # Whether the first-order correction is in the program: where the models are chosen by
    # the predicted-error rule (any iteration may choose it) or forced to "first-order".
    first_order: bool = True
    # Whether any periodic-orbit record carries a stepped sine's sweep direction (then its
    # orbit starts from `GroupData.sine_anchor`, see `_anchors.py`).
    sweeps: bool = False
    # Harmonics of the periodic-orbit model (`_orbit_model`)
    orbit_harmonics: int = ORBIT_HARMONICS


class GroupData(eqx.Module):
    """Records at one spindle speed (traced)."""

    sine_freq: jax.Array  # (R, H) harmonic frequencies [Hz]
    sine_force: jax.Array  # (R, H) complex force harmonics [N]
    sine_acc: jax.Array  # (R, H) complex measured acceleration harmonics [m/s^2]
    sine_scale: jax.Array  # (R, H, 2) std of (Re, Im); inf: not used (padding, filter band)
    # (R, H) complex mean rates of change of the force harmonics' envelopes [N/s, N/s^2]
    # (a drifting shaker: `_measurement.drift_terms`; zero for padding)
    sine_rate: jax.Array
    sine_rate2: jax.Array
    sine_first: jax.Array  # (R,) bool: first-order harmonic-balance correction added
    sine_orbit: jax.Array  # (R,) bool: periodic-orbit (harmonic balance) model
    orbit_index: jax.Array  # (S,) int: the records whose orbit is computed (padded)
    sine_sweep: jax.Array  # (R,) +1 / -1: a stepped sine swept up / down; 0: not given
    # (R, U) HB unknowns where each swept record's orbit starts (`_anchors.py`; zero: not
    # anchored, the measured state instead); (R, 0) where no record is swept.
    sine_anchor: jax.Array
    sweep_index: jax.Array  # (W,) int: the swept orbit records (padded by repeating one)
    frf_freq: jax.Array  # (L,) FRF lines [Hz]
    frf_acc: jax.Array  # (L,) complex accelerance [m/s^2 per N]
    frf_scale: jax.Array  # (L, 2)


class FitData(eqx.Module):
    """All traced inputs of the residual except theta."""

    base: object  # BallScrewParams: the prior parameter set (fitted stiffness keys explicit)
    speeds: jax.Array  # (G,) [r/min]
    prior_values: jax.Array  # (p,) file units
    inv_sigma: jax.Array  # (p,) 1 / prior std of theta; 0: no prior
    # (p,) the prior's centre in theta (zero; a randomised-maximum-likelihood refit draws it
    # from the prior, `_refits.py`)
    prior_shift: jax.Array
    info_floor: jax.Array  # () singular values below this carry no information (ML: 1)
    groups: tuple
    # () bool: the periodic-orbit records are modelled (False: a staged fit's first stage,
    # `masked_orbit_records`: their rows carry no data and no orbit is solved, in the same
    # compiled program as the full fit)
    orbits_on: jax.Array = True


def sweep_direction(d) -> float:
    """+1 / -1 for a sine record whose header says `sweep = up` / `down` (a stepped sine's
    direction), else 0."""
    meta = getattr(getattr(d, "record", None), "meta", None) or {}
    return {"up": 1.0, "down": -1.0}.get(str(meta.get("sweep", "")).strip().lower(), 0.0)


def sine_variance(problem, i, d) -> np.ndarray:
    """(H, 2) variance of sine record i's residual A - model(F), Re and Im per harmonic:
    the acceleration's own plus the force's through the model (`_force_noise.force_gains`
    where the record has them, else the linearised |G|^2)."""
    gain = problem.force_gain.get(i)
    if gain is None:
        return d.acceleration_var + np.abs(problem.transfer[i])[:, None] ** 2 * d.force_var
    h = d.harmonics.size
    return d.acceleration_var + np.einsum("kcmd,md->kc", gain[:h, :, :h, :], d.force_var)


def _sine_arrays(problem, idx, h, rows):
    freq = np.full((rows, h), _PAD_FREQUENCY_HZ) * np.arange(1, h + 1)
    force = np.zeros((rows, h), complex)
    acc = np.zeros((rows, h), complex)
    std = np.full((rows, h, 2), np.inf)
    rate = np.zeros((rows, h), complex)
    rate2 = np.zeros((rows, h), complex)
    data = problem.data
    for j, i in enumerate(idx):
        d = data[i]
        freq[j] = d.frequency_hz * d.harmonics
        force[j] = d.force
        acc[j] = d.acceleration
        if d.force_rate is not None:
            rate[j], rate2[j] = d.force_rate, d.force_rate2
        # Errors in both channels: var(A - G F) = var(A) + |G|^2 var(F), with G the model's
        # transfer where the models were chosen (a weight only; not differentiated); for a
        # periodic-orbit record the orbit's own derivatives (`_force_noise`).
        var = sine_variance(problem, i, d)
        # Harmonics near the anti-alias filter are left out (their phase is the filter's,
        # not the structure's): infinite std -> zero residual.
        std[j] = np.where((freq[j] <= problem.max_harmonic_hz)[:, None], np.sqrt(var), np.inf)
    return freq, force, acc, std, rate, rate2


def _frf_arrays(problem, idx, lines):
    freq = np.full(lines, _PAD_FREQUENCY_HZ)
    acc = np.zeros(lines, complex)
    std = np.full((lines, 2), np.inf)
    pos = 0
    for i in idx:
        d = problem.data[i]
        n = np.asarray(d.frequency_hz).size
        freq[pos:pos + n] = np.asarray(d.frequency_hz, float)
        acc[pos:pos + n] = np.asarray(d.accelerance, complex)
        # Lines the linear FRF cannot model within the model-error bound: infinite std.
        std[pos:pos + n] = np.sqrt(np.where(
            np.asarray(problem.frf_left_out.get(i, False))[..., None], np.inf,
            np.asarray(d.variance, float)))
        pos += n
    return freq, acc, std


def _members(problem, is_frf, s):
    data, models = problem.data, problem.models
    sine_idx = [i for i, d in enumerate(data) if d.speed_rpm == s and not is_frf(d)]
    frf_idx = [i for i, d in enumerate(data) if d.speed_rpm == s and is_frf(d)]
    orbit = [j for j, i in enumerate(sine_idx) if models[i] == "nonlinear"]
    n_lines = int(sum(np.asarray(data[i].frequency_hz).size for i in frf_idx))
    return sine_idx, frf_idx, orbit, n_lines


def _classes(sine_idx, orbit, n_lines) -> tuple:
    """(sine rows, orbit slots, FRF lines) of a speed group after padding."""
    return sine_rows(len(sine_idx)), size_class(len(orbit)), size_class(n_lines)


def padded_counts(problem, is_frf) -> dict:
    """{speed: (sine rows, orbit slots, FRF lines)} after padding to size classes."""
    out = {}
    for s in problem.speeds:
        sine_idx, _, orbit, n_lines = _members(problem, is_frf, s)
        out[s] = _classes(sine_idx, orbit, n_lines)
    return out


def build_data(problem, is_frf):
    """(`FitData`, `Structure`, layout) of a `Problem` (see the module docstring); padded
    further to `problem.pad`'s counts where it gives them."""
    data, models = problem.data, problem.models
    sines = [d for d in data if not is_frf(d)]
    h = sines[0].harmonics.size if sines else 1
    if problem.pad is not None:
        h = problem.pad["harmonics"]
    groups, layout, pos = [], {}, 0
    pad = {} if problem.pad is None else problem.pad["counts"]
    sweeps = any(sweep_direction(d) and m == "nonlinear" for d, m in zip(data, models))
    width = 6 + 12 * ORBIT_HARMONICS if sweeps else 0
    for gi, s in enumerate(problem.speeds):
        sine_idx, frf_idx, orbit, n_lines = _members(problem, is_frf, s)
        rows, slots, lines = (max(a, b) for a, b in zip(_classes(sine_idx, orbit, n_lines),
                                                        pad.get(s, (0, 0, 0))))
        orbit_index = np.asarray(orbit + [orbit[0] if orbit else 0] * (slots - len(orbit)),
                                 int)
        sf, sF, sA, sS, sR, sR2 = _sine_arrays(problem, sine_idx, h, rows)
        first = np.zeros(rows, bool)
        nl = np.zeros(rows, bool)
        sweep = np.zeros(rows)
        for j, i in enumerate(sine_idx):
            first[j] = models[i] == "first-order"
            nl[j] = models[i] == "nonlinear"
            sweep[j] = sweep_direction(data[i])
        swept = [j for j in orbit if sweep[j] != 0]
        swept += [swept[0] if swept else 0] * (size_class(len(swept)) - len(swept))
        ff, fA, fS = _frf_arrays(problem, frf_idx, lines)
        groups.append(GroupData(np.asarray(sf), np.asarray(sF), np.asarray(sA),
                                np.asarray(sS), np.asarray(sR), np.asarray(sR2),
                                np.asarray(first), np.asarray(nl),
                                np.asarray(orbit_index), np.asarray(sweep),
                                np.zeros((rows, width)), np.asarray(swept, int),
                                np.asarray(ff), np.asarray(fA),
                                np.asarray(fS)))
        for j, i in enumerate(sine_idx):
            layout[i] = (gi, 0, np.concatenate([pos + j * h + np.arange(h),
                                                pos + (rows + j) * h + np.arange(h)]), j)
        pos += 2 * rows * h
        start = 0
        for i in frf_idx:
            n = np.asarray(data[i].frequency_hz).size
            layout[i] = (gi, 1, np.concatenate([pos + start + np.arange(n),
                                                pos + lines + start + np.arange(n)]),
                         slice(start, start + n))
            start += n
        pos += 2 * lines
    sigma = problem.prior_sigma
    fit_data = FitData(
        problem.base, np.asarray(problem.speeds, float), np.asarray(problem.prior_values),
        np.asarray(np.zeros(problem.n_params) if sigma is None else 1.0 / np.asarray(sigma)),
        np.zeros(problem.n_params), np.asarray(problem.info_floor, float), tuple(groups),
        np.asarray(True))
    structure = Structure(tuple(problem.keys),
                          tuple(-1 if s is None else problem.speeds.index(s)
                                for s in problem.param_speeds),
                          tuple(bool(x) for x in problem.is_log), len(problem.speeds),
                          problem.may_use_first_order, sweeps)
    return fit_data, structure, layout


def masked_orbit_records(fit_data: FitData) -> FitData:
    """The same data with the periodic-orbit records left out: their rows carry no data
    (infinite standard errors: zero residual and Jacobian rows) and no orbit is solved
    (`orbits_on` False). Same layout, so the same compiled program."""
    groups = []
    for g in fit_data.groups:
        nl = np.asarray(g.sine_orbit)
        scale = np.where(nl[:, None, None], np.inf, np.asarray(g.sine_scale))
        groups.append(eqx.tree_at(lambda x: (x.sine_scale, x.sine_orbit), g,
                                  (scale, np.zeros_like(nl))))
    return eqx.tree_at(lambda d: (d.groups, d.orbits_on), fit_data,
                       (tuple(groups), np.asarray(False)))


def used_rows(fit_data: FitData) -> np.ndarray:
    """Data-residual rows that carry data (False: padding, harmonics left out)."""
    parts = []
    for g in fit_data.groups:
        for scale in (g.sine_scale, g.frf_scale):
            finite = np.isfinite(np.asarray(scale))
            parts.append(finite[..., 0].reshape(-1))
            parts.append(finite[..., 1].reshape(-1))
    return np.concatenate(parts) if parts else np.zeros(0, bool)
