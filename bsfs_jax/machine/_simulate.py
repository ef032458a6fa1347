"""Time simulation of the ball screw feed system (Eq. 31) and steady-state helpers."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._numerics import half_range
from ..model import Sinusoid, accelerations, joint_forces, vector_field
from ..params import BallScrewParams, validate
from ..solvers import RESULTS, SolverSettings, check_result, integrate
from ._system_arg import as_system


class Trajectory(eqx.Module):
    """A simulated response on a uniform grid of `samples_per_period` points per period.

    Arrays have time along axis 0 (and a leading batch axis under `vmap`). The grid starts
    after the transient at t = transient_periods * T and ends at the final time, so
    `stroboscopic()` returns the Poincare samples at t = kT.

    - `t` [s], `displacement`, `velocity`, `acceleration` [m, m/s, m/s^2], columns
      (bearing, screw, nut);
    - `joint_force` [N]: columns (F_b, F_s, F_n) of the bearing, screw and nut joints;
    - `force` [N]: the external force on the nut;
    - `result`: a `RESULTS` item (`RESULTS.successful` or the cause of the failure; the
      states of a failed run are NaN), `num_steps`, `period` [s].
    """

    t: jax.Array
    displacement: jax.Array
    velocity: jax.Array
    acceleration: jax.Array
    joint_force: jax.Array
    force: jax.Array
    result: RESULTS
    num_steps: jax.Array
    period: jax.Array
    samples_per_period: int = eqx.field(static=True)

    @property
    def ok(self) -> jax.Array:
        """Bool array: `result == RESULTS.successful`."""
        return self.result == RESULTS.successful

    @property
    def state(self):
        """(..., N, 6) states (x_b, x_s, x_n, v_b, v_s, v_n)."""
        return jnp.concatenate([self.displacement, self.velocity], axis=-1)

    def host_state(self) -> np.ndarray:
        """`state` as numpy, concatenated on the host (`state` outside jit compiles a
        program of its own for the concatenation)."""
        return np.concatenate([np.asarray(self.displacement), np.asarray(self.velocity)],
                              axis=-1)

    @property
    def final_state(self):
        return self.state[..., -1, :]

    def stroboscopic(self):
        """States at t = kT, shape (..., periods + 1, 6): the stroboscopic Poincare section."""
        return self.state[..., :: self.samples_per_period, :]

    def amplitude(self, dof: int = 2):
        """Half the peak-to-peak displacement [m] of a mass (default: the nut, x_n)."""
        x = self.displacement[..., dof]
        return half_range(x, axis=-1)


@dataclasses.dataclass(frozen=True)
class Horizon:
    """How long to run: transient periods discarded, then `periods` saved periods."""

    periods: int = 50
    transient_periods: int = 200
    samples_per_period: int = 64

    def __post_init__(self):
        for name in ("periods", "samples_per_period"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if int(self.transient_periods) < 0:
            raise ValueError(f"transient_periods must be >= 0, got {self.transient_periods}")


def simulate_core(model, forcing, y0=None, horizon: Horizon = Horizon(),
                  settings: SolverSettings = SolverSettings(), *, adjoint=None,
                  progress: bool = False) -> Trajectory:
    """Traceable simulation (no checks, no raising): use inside your own jit/vmap/grad."""
    system = as_system(model)
    period = forcing.period
    spp = horizon.samples_per_period
    n_save = horizon.periods * spp + 1
    t_start = horizon.transient_periods * period
    t_end = (horizon.transient_periods + horizon.periods) * period
    ts = t_start + period * jnp.arange(n_save) / spp
    ts = ts.at[-1].set(t_end)
    y0 = jnp.zeros(6) if y0 is None else jnp.asarray(y0, dtype=float)
    res = integrate(vector_field, y0, (system, forcing), 0.0, t_end, ts, settings,
                    adjoint=adjoint, progress=progress, throw=False)
    x, v = res.ys[:, :3], res.ys[:, 3:]
    force = jax.vmap(forcing)(ts)
    acc = accelerations(system, x, v, force)
    return Trajectory(ts, x, v, acc, joint_forces(system, x), force, res.result,
                      res.num_steps, period, spp)


_simulate_jit = eqx.filter_jit(simulate_core)


def simulate(model, *, frequency_hz=None, force_n=None, forcing=None, y0=None,
             periods: int = 50, transient_periods: int = 200, samples_per_period: int = 64,
             rtol: float = 1e-8, atol: float = 1e-12, max_steps: int = 1_000_000,
             solver: str = "tsit5", adjoint=None, progress: bool = False,
             throw: bool = True) -> Trajectory:
    """Simulate the BSFS under harmonic forcing on the nut (paper Eq. 31), adaptively.

    **Main arguments:**
    - `model`: `BallScrewParams` (built with its thermal chain) or a `System`.
    - `frequency_hz`, `force_n`: excitation P sin(2 pi f t) on the nut, or
    - `forcing`: any forcing Module with `__call__(t)` and `period` (e.g. `HarmonicForcing`).
    - `y0`: initial state (x_b, x_s, x_n, v_b, v_s, v_n); default: at rest at x = 0.

    **Horizon:** `transient_periods` are integrated and discarded, then `periods` periods
    are saved with `samples_per_period` points each (so t = kT samples are exact).

    **Numerics:** `rtol`, `atol` (adaptive PID controller), `max_steps`, `solver`
    ("tsit5", "dopri5", "dopri8", "kvaerno5"), `adjoint` (diffrax adjoint for gradients).

    **Returns:** a `Trajectory`. With `throw=True` (default) a failed solve (max steps,
    non-finite state, step-size failure) raises `SolverError` naming the cause and the
    settings; under jit/vmap pass `throw=False` and check `trajectory.result` (or `.ok`).
    """
    if forcing is None:
        if frequency_hz is None or force_n is None:
            raise ValueError("give frequency_hz and force_n, or a forcing Module")
        forcing = Sinusoid(force_n, frequency_hz)
    if isinstance(frequency_hz, int | float) and not frequency_hz > 0:
        raise ValueError(f"frequency_hz must be positive, got {frequency_hz}")
    if isinstance(model, BallScrewParams):
        validate(model)  # concrete values only; a no-op for traced ones
    horizon = Horizon(int(periods), int(transient_periods), int(samples_per_period))
    settings = SolverSettings(float(rtol), float(atol), int(max_steps), solver)
    traj = _simulate_jit(model, forcing, y0, horizon, settings, adjoint=adjoint,
                         progress=progress)
    if throw:
        context = (f"excitation {_describe(forcing)}, {horizon.transient_periods} transient + "
                   f"{horizon.periods} saved periods")
        check_result(traj.result, settings, context)
    return traj


def _describe(forcing) -> str:
    try:
        f = float(np.max(np.asarray(forcing.frequency)))
        a = float(np.max(np.asarray(getattr(forcing, "amplitude", np.nan))))
        return f"{f:g} Hz" + ("" if a != a else f", {a:g} N")
    except (TypeError, jax.errors.ConcretizationTypeError,
            jax.errors.TracerArrayConversionError):
        return type(forcing).__name__
