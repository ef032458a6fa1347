"""Periodic orbits of the forced BSFS with an implicit (IFT) reverse-mode derivative.

FALLBACK, to be merged with `bsfs_jax.solvers.shoot` by the lead: when this module was
written the shared shooting solver (`solvers/_shooting.py`) did not exist yet. The design
metrics need reverse-mode gradients with respect to many parameters, which a
forward-mode (diffrax `ForwardMode`) JVP cannot give by transposition, so the
derivative here is written by hand as a `jax.custom_vjp`:

    F(y, p) = phi_T(y; p) - y = 0        (period map at the forcing period T)
    dy*/dp  = -(M - I)^(-1) d(phi_T)/dp,  M = d(phi_T)/dy  (the monodromy matrix)
    p_bar   = w^T d(phi_T)/dp,  with (M - I)^T w = -y_bar

so the backward pass is one linear 6x6 solve plus ONE reverse pass through ONE period of
the flow (never through the transient or the Newton iterations).

The forward pass: a linear-FRF initial guess, a short transient (`transient_periods`,
no gradient), then Newton on F with the monodromy from the variational equations
(state and 6x6 fundamental matrix integrated together).
"""

import dataclasses

import jax
import jax.numpy as jnp

from ..model import Sinusoid, System, vector_field
from ..solvers import SolverSettings, integrate, linear_frf


@dataclasses.dataclass(frozen=True)
class OrbitSettings:
    """Numerical settings of the periodic-orbit solve (static: a change recompiles).

    - `transient_periods`: periods integrated from the linear-FRF guess before Newton.
    - `newton_steps`, `newton_tol`: at most this many Newton steps; converged when the
      scaled residual |phi_T(y) - y| (micrometres and micrometres * omega) is below tol.
    - `samples_per_period`: samples of the orbit used to find its extremes.
    - `rtol`, `atol`, `max_steps`, `solver`: integrator settings (see `SolverSettings`).
    - `frc_points`, `frc_band`, `frc_refinements`: the FRC-peak search (metric
      "frc_peak"): orbits at `frc_points` frequencies over `frc_band` x f1, then
      `frc_refinements` rounds of three-point parabolic refinement.
    """

    transient_periods: int = 10
    newton_steps: int = 12
    newton_tol: float = 1e-8
    samples_per_period: int = 64
    rtol: float = 1e-10
    atol: float = 1e-15
    max_steps: int = 200_000
    solver: str = "tsit5"
    frc_points: int = 13
    frc_band: tuple = (0.8, 1.2)
    frc_refinements: int = 4

    @property
    def solver_settings(self) -> SolverSettings:
        return SolverSettings(self.rtol, self.atol, self.max_steps, self.solver)


def _flow(system, forcing, y0, period, settings: OrbitSettings):
    """phi_T(y0): the state one forcing period later (plain 6-state integration)."""
    res = integrate(vector_field, y0, (system, forcing), 0.0, period, jnp.stack([period]),
                    settings.solver_settings)
    return res.ys[0]


def _variational_field(t, z, args):
    y, phi = z[:6], z[6:].reshape(6, 6)
    f, tangent = jax.linearize(lambda yy: vector_field(t, yy, args), y)
    dphi = jax.vmap(tangent, in_axes=1, out_axes=1)(phi)
    return jnp.concatenate([f, dphi.reshape(36)])


def flow_and_monodromy(system, forcing, y0, settings: OrbitSettings):
    """(phi_T(y0), M) with M = d phi_T / d y0 from the variational equations."""
    period = forcing.period
    z0 = jnp.concatenate([y0, jnp.eye(6).reshape(36)])
    res = integrate(_variational_field, z0, (system, forcing), 0.0, period,
                    jnp.stack([period]), settings.solver_settings)
    z = res.ys[0]
    return z[:6], z[6:].reshape(6, 6)


def _scale(forcing):
    """Per-component scale of the state: micrometres and micrometres * omega."""
    omega = 2.0 * jnp.pi * forcing.frequency
    return jnp.concatenate([jnp.full(3, 1e-6), jnp.full(3, 1e-6) * omega])


def linear_guess(system: System, forcing: Sinusoid):
    """Steady state of the linearised system at t = 0 for P sin(omega t) on the nut."""
    h = linear_frf(system, forcing.frequency)[0]  # (3,) complex receptance [m/N]
    omega = 2.0 * jnp.pi * forcing.frequency
    x0 = forcing.amplitude * jnp.imag(h * jnp.exp(1j * forcing.phase))
    v0 = forcing.amplitude * omega * jnp.real(h * jnp.exp(1j * forcing.phase))
    return jnp.concatenate([x0, v0])


def _newton(system, forcing, y_start, settings: OrbitSettings):
    scale = _scale(forcing)

    def step(carry):
        y, _, _, i = carry
        y_t, mono = flow_and_monodromy(system, forcing, y, settings)
        r = (y_t - y) / scale
        # Scaled Jacobian of the scaled residual: S^-1 (M - I) S.
        jac = (mono - jnp.eye(6)) * scale[None, :] / scale[:, None]
        dy = jnp.linalg.solve(jac, -r) * scale
        return y + dy, jnp.max(jnp.abs(r)), mono, i + 1

    def cond(carry):
        _, res, _, i = carry
        return (i < settings.newton_steps) & (res > settings.newton_tol) & jnp.isfinite(res)

    init = (y_start, jnp.asarray(1e30), jnp.eye(6), jnp.asarray(0))
    y, res, mono, iters = jax.lax.while_loop(cond, step, init)
    # `res` and `mono` belong to the last Newton iterate before its final update: the
    # returned point is at least that accurate (Newton converges quadratically), and the
    # monodromy there differs from the one at y by O(res), far below what the implicit
    # derivative needs. This saves one variational integration per solve.
    return y, res, mono, iters


def _solve_forward(system, forcing, y_guess, settings):
    period = forcing.period
    if settings.transient_periods > 0:
        t_end = settings.transient_periods * period
        y_start = integrate(vector_field, y_guess, (system, forcing), 0.0, t_end,
                            jnp.stack([t_end]), settings.solver_settings).ys[0]
        # A diverged transient: fall back on the guess itself.
        y_start = jnp.where(jnp.all(jnp.isfinite(y_start)), y_start, y_guess)
    else:
        y_start = y_guess
    return _newton(system, forcing, y_start, settings)


def _orbit_impl(settings, system, forcing, y_guess):
    y, res, _, iters = _solve_forward(system, forcing, y_guess, settings)
    return y, res, iters


_orbit = jax.custom_vjp(_orbit_impl, nondiff_argnums=(0,))


def _orbit_fwd(settings, system, forcing, y_guess):
    y, res, mono, iters = _solve_forward(system, forcing, y_guess, settings)
    return (y, res, iters), (y, mono, system, forcing, y_guess)


def _orbit_bwd(settings, saved, cotangents):
    y, mono, system, forcing, y_guess = saved
    y_bar = cotangents[0]
    w = jnp.linalg.solve((mono - jnp.eye(6)).T, -y_bar)
    _, vjp = jax.vjp(lambda s, f: _flow(s, f, y, f.period, settings), system, forcing)
    system_bar, forcing_bar = vjp(w)
    return system_bar, forcing_bar, jnp.zeros_like(y_guess)


_orbit.defvjp(_orbit_fwd, _orbit_bwd)


def periodic_orbit(system: System, forcing: Sinusoid, settings: OrbitSettings = OrbitSettings(),
                   y_guess=None):
    """(y*, residual, newton_iterations): the T-periodic orbit's state at t = 0 (mod T).

    Differentiable in reverse mode with respect to `system` and `forcing` by the implicit
    function theorem (see the module docstring). `residual` is the scaled max-norm of
    phi_T(y*) - y*; a value above `settings.newton_tol` means Newton did not converge.
    """
    if y_guess is None:
        y_guess = jax.lax.stop_gradient(linear_guess(system, forcing))
    return _orbit(settings, system, forcing, y_guess)


def orbit_samples(system: System, forcing: Sinusoid, y0, settings: OrbitSettings):
    """States (N + 1, 6) at N + 1 equally spaced times over one period from y0."""
    period = forcing.period
    n = settings.samples_per_period
    ts = period * jnp.arange(n + 1) / n
    res = integrate(vector_field, y0, (system, forcing), 0.0, period, ts,
                    settings.solver_settings)
    return ts, res.ys
