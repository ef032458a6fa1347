"""A synthetic 120 Hz exciter record shared by the record-loader tests (CSV/UFF58, TDMS)."""

import numpy as np

FS = 10240.0
F0 = 120.0
META = dict(frequency_hz=F0, force_amplitude_n=100.0, sample_rate_hz=FS, speed_rpm=2000.0,
            ambient_c=20.0)


def signals(n=4096, seed=0):
    """(time, force, acceleration): 100 N at F0 with a 4 N second harmonic, and noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    force = 100 * np.sin(2 * np.pi * F0 * t + 0.3) + 4 * np.sin(4 * np.pi * F0 * t) \
        + rng.normal(0, 1, n)
    acc = 0.4 * np.sin(2 * np.pi * F0 * t + 0.31) + rng.normal(0, 0.005, n)
    return t, force, acc
