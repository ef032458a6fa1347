"""How motion labels are verified (`VerifySettings`), and the names of the verdicts."""

import dataclasses

import jax

from ..solvers import CHECK_SETTINGS, SolverSettings

FAILED = "failed"


@dataclasses.dataclass(frozen=True)
class VerifySettings:
    """How labels are verified (static; see the module docstring).

    - `max_period`: largest n of period-n orbits looked for.
    - `orbit_tol`, `orbit_max_steps`, `orbit_settings`: Newton's relative tolerance on the
      scaled residual, its (chord) iterations, and the ODE settings of the orbit checks;
      `jac_tol`: where the orbit lies further than this (scaled) from the sampled state,
      its multipliers are evaluated again at the orbit.
    - `near_tol`: scaled stroboscopic distance under which the samples sit on the orbit
      (the sweep's own integration error is ~1e-7 of the amplitude); farther samples
      must follow the orbit's linearisation, e_{j+n} = M e_j, to a relative misfit
      below `linear_tol` (so they decay onto it: every multiplier is inside the unit
      circle). A trajectory on another attractor does not.
    - `separation_tol`: an n-periodic orbit whose states after m | n periods lie within
      this (scaled) of its start is a period-m orbit solved over n periods, and is not
      counted as period-n (Newton's tolerance leaves ~1e-6 errors in the states, so
      tighter tests miss it). Genuine period-n orbits closer to period m than this,
      just past a period doubling, stay unresolved.
    - `candidate_tol`: loose repetition tolerance that proposes period-n candidates.
    - `decay_folds`, `min_transient_periods`: the sweep's minimum transient is
      `decay_folds` time constants of the slowest linear mode (at least
      `min_transient_periods` periods).
    - `block_periods`, `block_samples`: length of one continuation block, and samples
      per period kept for its spectrum; `max_blocks`, `budget_time_constants`: when to
      give up (blocks, or time in units of the slowest decay time, but never before
      `min_blocks` blocks).
    - `align_periods`: tangent alignment periods dropped from the first block's growth.
    - `segments`: independent segments of the exponent's confidence interval.
    - `lyapunov_zero`: largest |lambda T| (and half-width) read as zero (a torus).
    - `drift_tol`: relative change of the section's mean and spread between blocks
      under which the trajectory has stopped drifting.
    - `rotation_tol`, `curve_tol`, `line_fraction_min`: torus and chaos thresholds.
    - `batch`: points checked in lockstep.
    - `wide`: run the orbit checks and the continuation blocks of a whole verification
      chunk as one batch, padded to a power of two (`lanes_for`), so one program serves
      every call: on an accelerator a lockstep batch costs its slowest lane's steps times
      a launch-bound step whatever its width, and batches of `batch` would pay that once
      per 16 points. None (the default): wide where the default backend is not the CPU
      (where lockstep lanes cost their arithmetic, and narrow batches wait less).
    - `settle`, `settle_blocks`: before the continuation blocks (which integrate the
      tangent dynamics too, in lockstep), points without an orbit are first run on for up
      to `settle_blocks` blocks of `block_periods` by the sweep's own program, its record
      tried for orbits after each (`_sweep_engines.SettleRuns`); their time is not charged
      to the blocks' budget. None (the default): where the sweep's engine is the kernel
      (on a GPU a lane of the kernel runs its own loop, ~10x faster than a lockstep block).
    - `settle` and `kernel_checks` act through `sweep(..., verify=...)`, which builds the
      settle runner and the kernel settings; `verify_sweep` / `verify_points` take them
      as arguments (`settle=`, `kernel=`) and otherwise run neither.
    - `kernel_checks`: run the orbit checks on the per-lane kernel
      (`solvers.check_orbits_lanes`) with the sweep's kernel settings; None: where the
      sweep's engine is the kernel. Off by default until measured on a GPU: the build
      of its first form (the whole monodromy matrix on a lane, 42 components) had not
      finished after 260 s on an H200; the monodromy now takes one column a lane (12
      components), not yet built on a GPU (`benchmarks/bench_gpu.py --kernel-checks 1`).
    - `run_settings`: ODE settings of the continuation blocks (as a sweep's).
    """

    max_period: int = 16
    orbit_tol: float = 1e-6
    jac_tol: float = 1e-4
    orbit_max_steps: int = 16
    orbit_settings: SolverSettings = CHECK_SETTINGS
    near_tol: float = 1e-4
    separation_tol: float = 1e-3
    linear_tol: float = 0.25
    candidate_tol: float = 0.05
    decay_folds: float = 3.0
    min_transient_periods: int = 8
    block_periods: int = 256
    block_samples: int = 8
    max_blocks: int = 8
    min_blocks: int = 3
    budget_time_constants: float = 60.0
    align_periods: int = 16
    segments: int = 8
    lyapunov_zero: float = 0.01
    drift_tol: float = 0.02
    rotation_tol: float = 1e-3
    curve_tol: float = 0.05
    line_fraction_min: float = 0.99
    batch: int = 16
    wide: bool | None = None
    settle: bool | None = None
    settle_blocks: int = 2
    kernel_checks: bool | None = False
    run_settings: SolverSettings = SolverSettings(solver="dopri5-fused", max_steps=4_000_000)

    def __post_init__(self):
        if not 1 <= int(self.max_period) <= 64:
            raise ValueError(f"VerifySettings.max_period must be in 1..64, got {self.max_period}")
        if int(self.block_periods) < 4 * int(self.segments):
            raise ValueError("VerifySettings.block_periods must be at least 4 x segments")
        if not 0 <= int(self.align_periods) < int(self.block_periods):
            raise ValueError("VerifySettings.align_periods must be in [0, block_periods)")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def is_wide(self) -> bool:
        """`wide` resolved on this process's default backend."""
        return jax.default_backend() != "cpu" if self.wide is None else bool(self.wide)

    def lanes_for(self, points: int) -> int:
        """Lockstep lanes of the orbit checks for a verification chunk of `points` points:
        `batch`, or (wide) the chunk's size rounded up to a power of two (at least `batch`)."""
        b = int(self.batch)
        if not self.is_wide():
            return b
        return max(b, 1 << max(int(points) - 1, 0).bit_length())


#: Names and units of the per-point verdict arrays (all (D, N)).
VERDICT_FIELDS = {
    "motion": "label: period-n, quasi-periodic, chaotic, unresolved or failed",
    "verified": "true where the label carries its evidence",
    "period_n": "n of a verified period-n orbit (0 otherwise)",
    "amplitude": "half peak-to-peak of the observed coordinate (orbit or last block)",
    "orbit_residual": "scaled Newton residual of the orbit (NaN: no orbit)",
    "max_multiplier": "largest Floquet multiplier modulus (NaN: no orbit)",
    "lyapunov_per_period": "largest Lyapunov exponent x T (orbit: ln max|mu| / n)",
    "lyapunov_low": "95 % confidence interval of lambda T, low end",
    "lyapunov_high": "95 % confidence interval of lambda T, high end",
    "rotation_number": "rotation number of the section [turns per period]",
    "curve_error": "distance of the section from one smooth closed curve (relative)",
    "line_fraction": "power fraction in the strongest spectral lines",
    "transient": "time integrated before the evidence [time unit of the problem]",
    "reason": "why the label is (or is not) verified",
}
