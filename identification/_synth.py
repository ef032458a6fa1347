"""Realistic synthetic exciter records from any parameter set.

The response is the full nonlinear model (Eq. 31, adaptive Tsit5) driven by a force with
what a real shaker test has and the identification model does not: 2nd/3rd harmonic
distortion, slow amplitude drift, an arbitrary start phase, a start-up transient that is
discarded, an anti-alias filter on both channels (8th-order Butterworth at 0.4 fs, causal,
applied at 4x oversampling before decimation), DC offsets on both sensors and white sensor
noise at a given signal-to-noise ratio. Everything is seeded.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import bsfs_jax
from bsfs_jax.model import accelerations

from ._records import Record


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


def _antialias(x, fs_high, cutoff):
    from scipy.signal import butter, sosfilt

    sos = butter(8, cutoff, fs=fs_high, output="sos")
    return sosfilt(sos, x)


@eqx.filter_jit
def _respond(system, forcing, ts, settings):
    res = bsfs_jax.integrate(bsfs_jax.vector_field, jnp.zeros(6), (system, forcing), 0.0,
                             ts[-1], ts, settings, throw=False)
    x, v = res.ys[:, :3], res.ys[:, 3:]
    force = jax.vmap(forcing)(ts)
    return force, accelerations(system, x, v, force)[:, 2], res.result


def synthesize(params, frequency_hz: float, force_n: float, *, duration_s: float = 2.0,
               sample_rate_hz: float = 10240.0, effects: TestEffects = TestEffects(),
               seed: int = 0, rtol: float = 1e-8, atol: float = 1e-12) -> Record:
    """A synthetic record of `duration_s` at `sample_rate_hz` (see the module docstring).

    The metadata carries frequency, force, sample rate, speed, ambient temperature and
    `synthetic = "true"`. Raises `bsfs_jax.SolverError` if the simulation fails.
    """
    rng = np.random.default_rng(seed)
    f = float(frequency_hz)
    fs_hi = sample_rate_hz * effects.oversample
    n_settle = int(round(effects.settle_s * fs_hi))
    n_rec = int(round(duration_s * sample_rate_hz))
    n_hi = n_settle + n_rec * effects.oversample
    ts = jnp.arange(1, n_hi + 1) / fs_hi
    forcing = ShakerForce(*(jnp.asarray(v, dtype=float) for v in (
        force_n, f, rng.uniform(0, 2 * np.pi), effects.h2, effects.h3,
        rng.uniform(0, 2 * np.pi), rng.uniform(0, 2 * np.pi), effects.drift,
        effects.drift_frequency_hz, rng.uniform(0, 2 * np.pi))))
    settings = bsfs_jax.SolverSettings(rtol=rtol, atol=atol, max_steps=4_000_000)
    system = bsfs_jax.build_system(params)
    force, acc, result = _respond(system, forcing, ts, settings)
    from bsfs_jax.solvers import check_result

    check_result(result, settings, f"synthetic record {f:g} Hz, {force_n:g} N")
    force, acc = np.asarray(force), np.asarray(acc)
    cutoff = 0.4 * sample_rate_hz
    force = _antialias(force, fs_hi, cutoff)[n_settle::effects.oversample]
    acc = _antialias(acc, fs_hi, cutoff)[n_settle::effects.oversample]
    rms = lambda x: float(np.sqrt(np.mean((x - np.mean(x)) ** 2)))
    force = (force + effects.force_dc_n
             + rng.normal(0, rms(force) * 10 ** (-effects.force_snr_db / 20), force.size))
    acc = (acc + effects.accel_dc_m_s2
           + rng.normal(0, rms(acc) * 10 ** (-effects.accel_snr_db / 20), acc.size))
    t = np.arange(n_rec) / sample_rate_hz
    meta = {
        "frequency_hz": f,
        "force_amplitude_n": float(force_n),
        "sample_rate_hz": float(sample_rate_hz),
        "speed_rpm": float(np.asarray(params.thermal.speed_rpm)),
        "ambient_c": float(np.asarray(params.thermal.ambient_c)),
        "synthetic": "true",
        "seed": float(seed),
        "accel_snr_db": effects.accel_snr_db,
        "force_snr_db": effects.force_snr_db,
    }
    return Record(t, force, acc, f, float(force_n), float(sample_rate_hz), meta["speed_rpm"],
                  meta["ambient_c"], meta, f"synthetic_{f:g}Hz_{force_n:g}N")
