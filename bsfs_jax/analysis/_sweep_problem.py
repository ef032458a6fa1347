"""What a sweep varies and how each point is computed: `SweepProblem`, `SweepConfig`."""

import dataclasses
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax

from .._numerics import float_array
from ..solvers import RESULTS, SolverSettings, result_codes

MODES = ("cold", "continued")
DIRECTIONS = ("up", "down", "both")
ENGINES = ("auto", "map", "queue", "kernel")
OK = int(result_codes(RESULTS.successful))  # the code of a successful point in the arrays


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """How each sweep point is computed, and how points are batched (static: hashable).

    - `transient_periods`: forcing periods discarded before recording (cold starts;
      `sweep(..., transient=...)` may give cold points their own).
    - `continued_transient_periods`: the same for points continued from their neighbour.
    - `periods`: recorded periods (stroboscopic samples = periods + 1).
    - `samples_per_period`: samples per period of the observed coordinate for the
      spectrum and the amplitude (the spectrum reaches samples_per_period / 2 harmonics).
    - `lyapunov`: also integrate the tangent dynamics (largest Lyapunov exponent; about
      doubles the cost of the recorded periods).
    - `lyapunov_align_periods`: the last periods of each transient in which the tangent
      vector is integrated (and renormalised) before its growth is recorded, so that it
      has aligned with the most unstable direction; must be shorter than either transient.
    - `batch_size`: points integrated in lockstep (vmap) inside `lax.map`; 0 = whole chunk.
    - `chunk_size`: points per jit call and per checkpoint file.
    - `window`: FFT window ("hann" or "rect").
    - `engine` (cold mode): "map" (`lax.map` over lockstep batches of `batch_size`),
      "queue" (`batch_size` lanes integrating equal time slices and taking the next point
      when done; without `lyapunov` only, falls back to "map" otherwise), "kernel" (one
      Pallas kernel in which every point runs its own adaptive loop,
      `solvers.integrate_lanes`: Triton on a GPU, interpret mode elsewhere, which is slow
      and meant for tests; needs the problem's `component_field`, without `lyapunov`), or
      "auto" (the default: "kernel" on a GPU where it applies, else "map").
    - `kernel_block`: kernel engine: points per Triton program (one warp runs 32).
    - `kernel_fast`: kernel engine: the controller's arithmetic without float64 divisions
      and powers (`integrate_lanes(fast=True)`, the default); False repeats the fused
      loop's controller to the bit. The field is the problem's `component_field` either way.
    - `kernel_unroll`: kernel engine: steps per test of the loop's block-wide condition
      (`integrate_lanes(unroll=...)`; the same results for any value).
    - `kernel_looped`: kernel engine: the step's stages as a loop, the field inlined once
      (`integrate_lanes(looped=...)`; the same method to rounding). The default: on an
      H200 its program compiled in 4.4 s against 13.5 s unrolled, for a run 1.23x as long
      (B1, 2048 points: 1.69 against 1.38 s; benchmarks/results/gpu_b1.md); False where
      one program runs many times.
    - `max_slice_periods`: queue engine: at most this many periods per slice.
    - `settings`: `SolverSettings` (tolerances, max_steps, solver; default the fused
      Dormand-Prince 5(4) loop "dopri5-fused", or any diffrax solver name).
    """

    transient_periods: int = 200
    continued_transient_periods: int = 20
    periods: int = 64
    samples_per_period: int = 32
    lyapunov: bool = True
    lyapunov_align_periods: int = 16
    batch_size: int = 8
    chunk_size: int = 16
    window: str = "hann"
    engine: str = "auto"
    kernel_block: int = 32
    kernel_fast: bool = True
    kernel_unroll: int = 1
    kernel_looped: bool = True
    max_slice_periods: int = 64
    # Sweeps are forward-only, so they default to the fused Dormand-Prince loop (about 3x
    # cheaper per step than diffrax's general loop here; cross-checked in tests/test_fused.py).
    settings: SolverSettings = SolverSettings(solver="dopri5-fused")

    def __post_init__(self):
        for name in ("transient_periods", "continued_transient_periods", "periods",
                     "samples_per_period", "chunk_size"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"SweepConfig.{name} must be >= 1, got {getattr(self, name)}")
        limit = min(self.transient_periods, self.continued_transient_periods)
        if self.lyapunov and not 0 <= int(self.lyapunov_align_periods) < limit:
            raise ValueError(
                "SweepConfig.lyapunov_align_periods must be >= 0 and smaller than both "
                f"transients ({limit}), got {self.lyapunov_align_periods}")
        if int(self.batch_size) < 0:
            raise ValueError(f"SweepConfig.batch_size must be >= 0, got {self.batch_size}")
        if self.engine not in ENGINES:
            raise ValueError(f"SweepConfig.engine must be one of {', '.join(ENGINES)}, got "
                             f"{self.engine!r}")
        if int(self.kernel_block) < 1:
            raise ValueError(f"SweepConfig.kernel_block must be >= 1, got {self.kernel_block}")
        if int(self.kernel_unroll) < 1:
            raise ValueError(
                f"SweepConfig.kernel_unroll must be >= 1, got {self.kernel_unroll}")
        if self.window not in ("hann", "rect"):
            raise ValueError(f"SweepConfig.window must be 'hann' or 'rect', got {self.window!r}")

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        return d


class SweepProblem(eqx.Module):
    """A periodically forced system and the scalar parameter a sweep varies (generic).

    - `vector_field`: f(t, y, args) (diffrax signature; module-level function or Module).
    - `setup`: setup(data, value) -> (args, period): builds f's `args` and the forcing
      period [time unit] for parameter `value`; traceable (value is a traced scalar). The
      forcing must be periodic with that period from t = 0.
    - `data`: pytree of arrays that `setup` reads (traced: new values do not recompile).
    - `y0`: the state cold starts begin from.
    - `param`, `unit`: the swept parameter's name and unit (for files and plots).
    - `observe`: index of the state coordinate whose spectrum and amplitude are reported.
    - `state_names`, `state_units`, `time_unit`: labels for files and plots.
    - `component_field`: the same field on a tuple of state components, elementwise
      (`field(t, ys, args) -> tuple`, see `solvers.integrate_lanes`), for the kernel
      engine; None: that engine is not available for this problem.
    """

    vector_field: Callable = eqx.field(static=True)
    setup: Callable = eqx.field(static=True)
    data: Any
    y0: jax.Array = eqx.field(converter=float_array)
    param: str = eqx.field(static=True)
    unit: str = eqx.field(static=True, default="")
    observe: int = eqx.field(static=True, default=0)
    state_names: tuple = eqx.field(static=True, default=())
    state_units: tuple = eqx.field(static=True, default=())
    time_unit: str = eqx.field(static=True, default="s")
    component_field: Callable | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        n = self.y0.shape[-1] if self.y0.ndim else 0
        if self.y0.ndim != 1:
            raise ValueError(f"SweepProblem.y0 must be a 1-D state, got shape {self.y0.shape}")
        if not 0 <= self.observe < n:
            raise ValueError(f"SweepProblem.observe={self.observe} is not a state index "
                             f"(state has {n} coordinates)")
        for name in ("state_names", "state_units"):
            v = getattr(self, name)
            if v and len(v) != n:
                raise ValueError(f"SweepProblem.{name} has {len(v)} entries for a state of {n}")

    @property
    def n_states(self) -> int:
        return int(self.y0.shape[0])

    def resolved_engine(self, config: "SweepConfig") -> str:
        """The cold-sweep engine `config.engine` means for this problem on this device."""
        fits = self.component_field is not None and not config.lyapunov
        if config.engine == "kernel":
            if not fits:
                raise ValueError(
                    "SweepConfig(engine='kernel') needs a problem with a component_field and "
                    "lyapunov off; use engine='map' or 'auto'")
            return "kernel"
        if config.engine == "auto":
            return "kernel" if fits and jax.default_backend() == "gpu" else "map"
        return config.engine

    def labels(self):
        n = self.n_states
        names = tuple(self.state_names) or tuple(f"y{i}" for i in range(n))
        units = tuple(self.state_units) or ("",) * n
        return names, units
