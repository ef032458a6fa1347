"""Realistic synthetic exciter records from any parameter set.

The response is the full nonlinear model (Eq. 31, adaptive Tsit5) driven by a force with
what a real shaker test has and the identification model does not: 2nd/3rd harmonic
distortion, slow amplitude drift, an arbitrary start phase, a start-up transient that is
discarded, an anti-alias filter on both channels (8th-order Butterworth at 0.4 fs, causal,
applied at 4x oversampling before decimation), DC offsets on both sensors and white sensor
noise at a given signal-to-noise ratio. Everything is seeded.

Three excitations (`excitation=`):

- `sine` (default): a stepped-sine record at `frequency_hz`, amplitude `force_n`;
- `chirp`: a burst chirp, a *linear* sweep from `start_hz` to `stop_hz` over the whole
  record at constant amplitude `force_n` (with the shaker's distortion and drift), with
  sin^2 tapers over the first and last 2 % of the record, started from rest (no transient
  to discard). Linear rather than logarithmic: equal time, hence equal force energy, per Hz,
  so the FRF's lines have a uniform signal-to-noise ratio on the linear frequency grid;
- `random`: seeded Gaussian noise band-limited to `start_hz`..`stop_hz` (ideal band-pass
  of white noise), RMS `force_n`, with the drift; its start-up transient is discarded.
  It drives the model through `SampledForce`, a Catmull-Rom (C1 cubic) interpolation of the
  4x oversampled signal: at 2 kHz on a 40.96 kHz grid it passes the signal within 1e-5
  (linear interpolation would lose 0.8 %).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import bsfs_jax
from bsfs_jax.model import accelerations
from bsfs_jax.solvers import RESULTS, result_codes

from ..measurement import require_x64
from ..records import Record


class ShakerForce(eqx.Module):
    """Shaker force with distortion and drift (all fields are arrays).

    (1 + d sin(2 pi f_d t + phi_d)) P [sin(w t + phi) + h2 sin(2 w t + phi2)
    + h3 sin(3 w t + phi3)].
    """

    amplitude: jax.Array
    frequency: jax.Array
    phase: jax.Array
    h2: jax.Array
    h3: jax.Array
    phase2: jax.Array
    phase3: jax.Array
    drift: jax.Array
    drift_frequency: jax.Array
    drift_phase: jax.Array

    @property
    def period(self):
        return 1.0 / self.frequency

    def __call__(self, t):
        w = 2.0 * jnp.pi * self.frequency
        wave = (jnp.sin(w * t + self.phase) + self.h2 * jnp.sin(2 * w * t + self.phase2)
                + self.h3 * jnp.sin(3 * w * t + self.phase3))
        env = 1.0 + self.drift * jnp.sin(2 * jnp.pi * self.drift_frequency * t + self.drift_phase)
        return self.amplitude * env * wave


class ChirpForce(eqx.Module):
    """Burst chirp: w(t) (1 + d sin(2 pi f_d t + phi_d)) P [sin(phi) + h2 sin(2 phi + phi2)
    + h3 sin(3 phi + phi3)], phi = 2 pi (f0 t + r t^2 / 2) + phi0, for 0 <= t <= T; w rises
    and falls as sin^2 over `taper` seconds at both ends and is 0 outside [0, T]."""

    amplitude: jax.Array
    start: jax.Array
    rate: jax.Array
    duration: jax.Array
    taper: jax.Array
    phase: jax.Array
    h2: jax.Array
    h3: jax.Array
    phase2: jax.Array
    phase3: jax.Array
    drift: jax.Array
    drift_frequency: jax.Array
    drift_phase: jax.Array

    def __call__(self, t):
        phi = 2.0 * jnp.pi * (self.start * t + 0.5 * self.rate * t**2) + self.phase
        ramp = jnp.clip(jnp.minimum(t, self.duration - t) / self.taper, 0.0, 1.0)
        wave = (jnp.sin(phi) + self.h2 * jnp.sin(2 * phi + self.phase2)
                + self.h3 * jnp.sin(3 * phi + self.phase3))
        env = 1.0 + self.drift * jnp.sin(2 * jnp.pi * self.drift_frequency * t + self.drift_phase)
        return self.amplitude * jnp.sin(0.5 * jnp.pi * ramp) ** 2 * env * wave


class SampledForce(eqx.Module):
    """A force sampled at t0 + k dt, k = 0..N-1, interpolated by Catmull-Rom cubics (C1,
    exact at the samples); held at the end values outside the grid. `padded` is the sample
    array with one extra value at the start and two at the end (see `from_samples`)."""

    padded: jax.Array
    t0: jax.Array
    dt: jax.Array

    @classmethod
    def from_samples(cls, values, t0: float, dt: float) -> SampledForce:
        v = jnp.asarray(values, dtype=float)
        return cls(jnp.concatenate([v[:1], v, v[-1:], v[-1:]]), jnp.asarray(t0, dtype=float),
                   jnp.asarray(dt, dtype=float))

    def __call__(self, t):
        u = (t - self.t0) / self.dt
        k = jnp.clip(jnp.floor(u), 0, self.padded.shape[0] - 5)
        s = jnp.clip(u - k, 0.0, 1.0)
        k = k.astype(int)
        p0, p1, p2, p3 = (self.padded[k + j] for j in range(4))
        return p1 + 0.5 * s * (p2 - p0 + s * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3
                                              + s * (3.0 * (p1 - p2) + p3 - p0)))


@dataclasses.dataclass(frozen=True)
class TestEffects:
    """Imperfections of a real test (defaults: a decent electrodynamic-shaker set-up)."""

    accel_snr_db: float = 35.0  # accelerometer SNR (signal RMS / noise RMS)
    force_snr_db: float = 40.0  # force sensor SNR
    h2: float = 0.04  # 2nd harmonic distortion of the exciter force (relative)
    h3: float = 0.02  # 3rd harmonic
    drift: float = 0.03  # slow relative amplitude drift
    drift_frequency_hz: float = 0.3
    force_dc_n: float = 1.5  # sensor DC offsets
    accel_dc_m_s2: float = 0.02
    settle_s: float = 0.25  # start-up transient simulated and discarded
    oversample: int = 4
    antialias_order: int = 8  # Butterworth order of the anti-alias filter (0: none)


def _antialias(order, cutoff, fs_high):
    """x -> x through the Butterworth anti-alias filter (designed once; order 0: none)."""
    from scipy.signal import butter, sosfilt

    if order == 0:
        return lambda x: x
    sos = butter(order, cutoff, fs=fs_high, output="sos")
    return lambda x: sosfilt(sos, x)


# Output samples (at the oversampled rate) per integration segment: a record of any length
# is integrated as a loop over segments of this many samples, each by one compiled program
# (its state carried from the last), so that neither the program nor its save array grows
# with the record (60 s at 25.6 kHz, 4x oversampled, is 6.1 M samples).
SEGMENT = 1 << 15


def _window(forcing, k0: int, size: int):
    """`forcing` for the segment whose first sample interval starts at oversampled sample
    k0: a `SampledForce` cut to the samples that segment reads (the same interpolant
    there), any other force as it is."""
    if not isinstance(forcing, SampledForce):
        return forcing
    padded = forcing.padded
    idx = np.minimum(np.arange(k0, k0 + size + 4), padded.shape[0] - 1)
    return SampledForce(padded[idx], forcing.t0 + k0 * forcing.dt, forcing.dt)


@eqx.filter_jit
def _segment(system, forcing, y0, t_start, dt, n_valid, settings, size: int):
    """One segment: from state y0 at t_start, the force and the worktable acceleration at
    t_start + k dt, k = 1..size, integrated to t_start + n_valid dt (the samples past it
    repeat that time); and the state there, and the solver's result."""
    t1 = t_start + n_valid * dt
    ts = jnp.minimum(t_start + dt * jnp.arange(1, size + 1), t1)
    res = bsfs_jax.integrate(bsfs_jax.vector_field, y0, (system, forcing), t_start, t1, ts,
                             settings, throw=False)
    x, v = res.ys[:, :3], res.ys[:, 3:]
    force = jax.vmap(forcing)(ts)
    last = res.ys[jnp.maximum(n_valid - 1, 0)]
    return force, accelerations(system, x, v, force)[:, 2], last, res.result


@eqx.filter_jit
def _segment_many(system, forcings, y0s, t_start, dt, n_valid, settings, size: int):
    return jax.vmap(lambda f, y0: _segment(system, f, y0, t_start, dt, n_valid, settings,
                                           size))(forcings, y0s)


def _respond(system, forcings, y0s, n_hi: int, fs_hi: float, settings, progress=None):
    """(force, acceleration) (lanes, n_hi) at k / fs_hi, k = 1..n_hi, and the worst solver
    result, integrating segment by segment (`SEGMENT`). `progress(done, total)` is called
    after each segment where given."""
    size = min(SEGMENT, n_hi)
    lanes = len(forcings)
    force = np.empty((lanes, n_hi))
    acc = np.empty((lanes, n_hi))
    y = y0s
    dt = 1.0 / fs_hi
    for k0 in range(0, n_hi, size):
        n_valid = min(size, n_hi - k0)
        windows = [_window(fc, k0, size) for fc in forcings]
        t_start = jnp.asarray(k0 * dt)
        if lanes == 1:
            f, a, last, result = _segment(system, windows[0], y[0], t_start, jnp.asarray(dt),
                                          jnp.asarray(n_valid), settings, size)
            f, a, last = f[None], a[None], last[None]
        else:
            stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *windows)
            f, a, last, result = _segment_many(system, stacked, y, t_start, jnp.asarray(dt),
                                               jnp.asarray(n_valid), settings, size)
        force[:, k0:k0 + n_valid] = np.asarray(f)[:, :n_valid]
        acc[:, k0:k0 + n_valid] = np.asarray(a)[:, :n_valid]
        y = last
        if np.any(np.atleast_1d(result_codes(result)) != result_codes(RESULTS.successful)):
            break  # the caller's `check_result` names the failure
        if progress is not None:
            progress(k0 + n_valid, n_hi)
    return force, acc, result


CHIRP_TAPER = 0.02  # fraction of the record in each sin^2 taper of a chirp
RANDOM_TAPER_S = 0.01  # fade-in of the random force at the start of its settling time


def synthesize(params, frequency_hz: float | None, force_n: float, *, duration_s: float = 2.0,
               sample_rate_hz: float = 10240.0, effects: TestEffects = TestEffects(),
               seed: int = 0, rtol: float = 1e-8, atol: float = 1e-12,
               excitation: str = "sine", start_hz: float | None = None,
               stop_hz: float | None = None, sweep: str | None = None,
               progress=None) -> Record:
    """A synthetic record of `duration_s` at `sample_rate_hz` (see the module docstring).

    `excitation`: "sine" (at `frequency_hz`, amplitude `force_n`), "chirp" (linear sweep
    `start_hz`..`stop_hz`, amplitude `force_n`) or "random" (band `start_hz`..`stop_hz`,
    RMS `force_n`); `frequency_hz` is not used for chirp and random (pass None). The
    metadata carries the excitation and its band, the force level, sample rate, speed,
    ambient temperature, seed and `synthetic = "true"`. Raises `ValueError` for a bad band
    and `bsfs_jax.SolverError` if the simulation fails.

    `sweep` ("up" or "down", sine only): a step of a stepped-sine sweep. The simulation
    starts on the periodic orbit that sweeping that way reaches (where the drive has two
    stable orbits near a fold, the branch the sweep follows), not from rest, and the header
    carries `sweep`.
    """
    return synthesize_many(params, frequency_hz, force_n, [seed], duration_s=duration_s,
                           sample_rate_hz=sample_rate_hz, effects=effects, rtol=rtol,
                           atol=atol, excitation=excitation, start_hz=start_hz,
                           stop_hz=stop_hz, sweep=sweep, progress=progress)[0]


def synthesize_many(params, frequency_hz: float | None, force_n: float, seeds, *,
                    duration_s: float = 2.0, sample_rate_hz: float = 10240.0,
                    effects: TestEffects = TestEffects(), rtol: float = 1e-8,
                    atol: float = 1e-12, excitation: str = "sine",
                    start_hz: float | None = None, stop_hz: float | None = None,
                    sweep: str | None = None, progress=None) -> list:
    """`synthesize` for several seeds at once: the same test repeated (new phases, noise and
    drift per seed), the simulations as lanes of one vmapped integration. Record k is the
    one `synthesize(..., seed=seeds[k])` makes: the same random draws in the same order, and
    the same response to the integration tolerance (vmapped lanes take their own steps;
    tests/test_identification.py checks 1e-6 of the peak). `progress(done, total)`, where
    given, is called as the integration advances (oversampled samples done and in all)."""
    require_x64("identification.synthesize")
    if excitation not in ("sine", "chirp", "random"):
        raise ValueError(f"excitation must be 'sine', 'chirp' or 'random', got {excitation!r}")
    if sweep not in (None, "up", "down") or (sweep and excitation != "sine"):
        raise ValueError(f"sweep must be 'up' or 'down' (sine records only), got {sweep!r}")
    rngs = [np.random.default_rng(s) for s in seeds]
    if not rngs:
        return []
    fs_hi = sample_rate_hz * effects.oversample
    n_rec = int(round(duration_s * sample_rate_hz))
    if excitation == "sine":
        if frequency_hz is None:
            raise ValueError("a sine record needs frequency_hz")
        f = float(frequency_hz)
        if not 0 < f < 0.4 * sample_rate_hz:
            raise ValueError(f"frequency_hz = {f:g}: a sine record needs 0 < frequency_hz < "
                             f"0.4 x the sample rate ({0.4 * sample_rate_hz:g} Hz)")
        n_settle = int(round(effects.settle_s * fs_hi))
        forcings = [ShakerForce(*(jnp.asarray(v, dtype=float) for v in (
            force_n, f, rng.uniform(0, 2 * np.pi), effects.h2, effects.h3,
            rng.uniform(0, 2 * np.pi), rng.uniform(0, 2 * np.pi), effects.drift,
            effects.drift_frequency_hz, rng.uniform(0, 2 * np.pi)))) for rng in rngs]
        what, name = f"{f:g} Hz, {force_n:g} N", f"synthetic_{f:g}Hz_{force_n:g}N"
        meta = {"frequency_hz": f, "force_amplitude_n": float(force_n)}
        if sweep:
            meta["sweep"] = sweep
    else:
        lo, hi = _band(start_hz, stop_hz, sample_rate_hz)
        n_settle = 0 if excitation == "chirp" else int(round(effects.settle_s * fs_hi))
        forcings = [_chirp(rng, force_n, lo, hi, n_rec / sample_rate_hz, effects)
                    if excitation == "chirp" else
                    _random(rng, force_n, lo, hi, n_settle + n_rec * effects.oversample,
                            fs_hi, effects) for rng in rngs]
        level = "force_amplitude_n" if excitation == "chirp" else "force_rms_n"
        what = f"{excitation} {lo:g}-{hi:g} Hz, {force_n:g} N"
        name = f"synthetic_{excitation}_{lo:g}-{hi:g}Hz_{force_n:g}N"
        meta = {"excitation": excitation, "start_hz": lo, "stop_hz": hi, level: float(force_n)}
        if excitation == "chirp":
            meta.update(sweep="linear", taper_s=CHIRP_TAPER * n_rec / sample_rate_hz)
    n_hi = n_settle + n_rec * effects.oversample
    settings = bsfs_jax.SolverSettings(rtol=rtol, atol=atol, max_steps=1_000_000)
    from bsfs_jax.machine import as_system  # the system by one program, not op by op
    from bsfs_jax.solvers import check_result

    system = as_system(params)

    y0s = jnp.stack([_start_state(system, fc, sweep) for fc in forcings])
    force, acc, result = _respond(system, forcings, y0s, n_hi, fs_hi, settings, progress)
    lanes = list(zip(force, acc))
    check_result(result, settings, f"synthetic record {what}")
    base = dict(meta, sample_rate_hz=float(sample_rate_hz),
                speed_rpm=float(np.asarray(params.thermal.speed_rpm)),
                ambient_c=float(np.asarray(params.thermal.ambient_c)), synthetic="true")
    cutoff = 0.4 * sample_rate_hz
    if effects.antialias_order:  # the record states its filter (`_antialias.py`)
        base.update(antialias_filter="butterworth",
                    antialias_order=float(effects.antialias_order),
                    antialias_cutoff_hz=float(cutoff), antialias_design_rate_hz=float(fs_hi))
    rms = lambda x: float(np.sqrt(np.mean((x - np.mean(x)) ** 2)))
    t = np.arange(n_rec) / sample_rate_hz
    f0 = meta.get("frequency_hz", float("nan"))
    records = []
    antialias = _antialias(effects.antialias_order, cutoff, fs_hi)
    for seed, rng, (force, acc) in zip(seeds, rngs, lanes):
        force = antialias(force)[n_settle::effects.oversample]
        acc = antialias(acc)[n_settle::effects.oversample]
        force = (force + effects.force_dc_n
                 + rng.normal(0, rms(force) * 10 ** (-effects.force_snr_db / 20), force.size))
        acc = (acc + effects.accel_dc_m_s2
               + rng.normal(0, rms(acc) * 10 ** (-effects.accel_snr_db / 20), acc.size))
        m = dict(base, seed=float(seed), accel_snr_db=effects.accel_snr_db,
                 force_snr_db=effects.force_snr_db)
        records.append(Record(t, force, acc, f0, float(force_n), float(sample_rate_hz),
                              m["speed_rpm"], m["ambient_c"], m, name))
    return records


def _start_state(system, forcing, sweep):
    """Rest, or for a stepped-sine step the swept orbit's state under the shaker's
    fundamental, P sin(w t + phi) = Re(P (sin phi - i cos phi) e^{i w t})."""
    if not sweep:
        return jnp.zeros(6)
    from ..measurement import swept_state

    fc = forcing.amplitude * jnp.asarray([jnp.sin(forcing.phase) - 1j * jnp.cos(forcing.phase)])
    y0, ok = swept_state(system, forcing.frequency, fc, 1.0 if sweep == "up" else -1.0)
    if not bool(ok):
        raise bsfs_jax.SolverError(f"no periodic orbit for the {sweep}-sweep start at "
                                   f"{float(forcing.frequency):g} Hz")
    return y0


def _band(start_hz, stop_hz, sample_rate_hz):
    if start_hz is None or stop_hz is None:
        raise ValueError("chirp and random records need start_hz and stop_hz")
    lo, hi = float(start_hz), float(stop_hz)
    if not 0 < lo < hi < 0.4 * sample_rate_hz:
        raise ValueError(f"need 0 < start_hz < stop_hz < 0.4 x sample rate "
                         f"({0.4 * sample_rate_hz:g} Hz), got {lo:g} and {hi:g}")
    return lo, hi


def _chirp(rng, force_n, lo, hi, duration, effects) -> ChirpForce:
    return ChirpForce(*(jnp.asarray(v, dtype=float) for v in (
        force_n, lo, (hi - lo) / duration, duration, CHIRP_TAPER * duration,
        rng.uniform(0, 2 * np.pi), effects.h2, effects.h3, rng.uniform(0, 2 * np.pi),
        rng.uniform(0, 2 * np.pi), effects.drift, effects.drift_frequency_hz,
        rng.uniform(0, 2 * np.pi))))


def _random(rng, force_n, lo, hi, n_hi, fs_hi, effects) -> SampledForce:
    n = n_hi + 1  # samples at t = 0 .. n_hi / fs_hi
    spec = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n, 1.0 / fs_hi)
    x = np.fft.irfft(np.where((f >= lo) & (f <= hi), spec, 0.0), n)
    t = np.arange(n) / fs_hi
    x *= force_n / np.sqrt(np.mean(x**2))
    x *= np.sin(0.5 * np.pi * np.clip(t / RANDOM_TAPER_S, 0.0, 1.0)) ** 2
    x *= 1.0 + effects.drift * np.sin(2 * np.pi * effects.drift_frequency_hz * t
                                      + rng.uniform(0, 2 * np.pi))
    return SampledForce.from_samples(x, 0.0, 1.0 / fs_hi)
