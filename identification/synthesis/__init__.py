"""Synthetic exciter records from the model, with a real test's imperfections.

`synthesize(params, frequency_hz, force_n, duration_s=..., sample_rate_hz=..., seed=...)`
-> `Record` (sine, chirp or random excitation; integrated in fixed segments, so any length
runs on one compiled program); `synthesize_many` (one test, several seeds, vmapped);
`TestEffects` (sensor noise, drift, force-cell error, anti-alias filter, oversampling).
"""

from ._synth import TestEffects as TestEffects
from ._synth import synthesize as synthesize
from ._synth import synthesize_many as synthesize_many
