"""Shooting: periodic orbits as fixed points of the period map (single or multiple).

The unknowns are the scaled states z = y / scale at the start of m segments of the orbit's
period n T (m = 1: single shooting). The residual is

    r_i = Phi_{t_i -> t_{i+1}}(z_i) - z_{i+1 mod m},        t_i = i n T / m,

integrated in scaled variables (`_Scaled`), so a single rtol/atol resolves micrometre
displacements and m/s velocities alike and the computed period map is smooth enough for
Newton to converge to tight tolerances. Multiple shooting (m > 1) keeps each integration
short: use it where one period is long compared with the fastest unstable growth (an
unstable orbit whose single-period map amplifies errors) or stiff. The Newton matrix holds
the segment Jacobians Phi_i' on its block diagonal; the monodromy matrix is their product.
"""

import dataclasses

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._integrate import FUSED_SOLVERS, SolverSettings, integrate
from ._method import AbstractOrbitMethod
from ._newton import residual_and_jacobian

#: ODE settings for shooting. Newton needs a period map that is smooth well below its
#: tolerance; an adaptive low-order solver's map jumps by about its global error when the
#: step sequence changes (the BSFS's contact kinks force many rejected steps). An 8th-order
#: solver at rtol 1e-11 brings that below 1e-9 at a similar number of steps. The
#: integration runs in scaled variables, so atol is relative to each component's size.
SHOOTING_SETTINGS = SolverSettings(rtol=1e-11, atol=1e-13, solver="dopri8")
#: The same steps by the fused 8(7) loop (`_fused.py`): a third to a quarter of the time
#: per period map, four times the compilation; for runs of thousands of corrector calls
#: (under a reverse-mode adjoint `integrate` runs diffrax's Dopri8 instead).
FUSED_SHOOTING_SETTINGS = SolverSettings(rtol=1e-11, atol=1e-13, solver="dopri8-fused")


def default_scale(y_guess):
    """Per-component scale from a guess: |y_i|, floored at 1e-3 max|y| (ones if all zero)."""
    y = jnp.abs(jnp.asarray(y_guess, dtype=float))
    peak = jnp.max(y)
    floor = jnp.where(peak > 0, 1e-3 * peak, 1.0)
    return jnp.maximum(y, jnp.broadcast_to(floor, y.shape))


def float_leaves_to_arrays(tree):
    """Python floats in `tree` -> 0-d arrays (so jit traces them rather than recompiling)."""
    def conv(x):
        if isinstance(x, float | complex) and not isinstance(x, bool):
            return jnp.asarray(x)
        return x

    return jax.tree_util.tree_map(conv, tree)


class Scaled(eqx.Module):
    """z' = f(t, z * scale, args) / scale: a vector field in scaled variables."""

    vector_field: object = eqx.field(static=True)

    def __call__(self, t, z, data):
        args, scale = data
        return self.vector_field(t, z * scale, args) / scale


def flow(vector_field, z0, args, scale, t0, t1, ts, settings, ode_adjoint=None):
    """Scaled states at `ts` (within [t0, t1]) from z0 at t0 (NaN where the solve failed)."""
    res = integrate(Scaled(vector_field), z0, (args, scale), t0, t1, ts, settings,
                    adjoint=ode_adjoint)
    return res.ys


def period_map(vector_field, y0, args, period, n_periods: int = 1,
               settings: SolverSettings = SHOOTING_SETTINGS, ode_adjoint=None):
    """Phi^n(y0): the state at t = n T from y0 at t = 0, in the system's units."""
    t1 = n_periods * jnp.asarray(period, dtype=float)
    res = integrate(vector_field, y0, args, jnp.zeros_like(t1), t1, t1[None], settings,
                    adjoint=ode_adjoint or dfx.ForwardMode())
    return res.ys[0]


def _variational(t, w, data):
    vector_field, args, d = data
    y, phi = w[:d], w[d:].reshape(d, d)
    f, lin = jax.linearize(lambda yy: vector_field(t, yy, args), y)
    return jnp.concatenate([f, jax.vmap(lin, in_axes=1, out_axes=1)(phi).reshape(-1)])


class _Variational(eqx.Module):
    vector_field: object = eqx.field(static=True)
    d: int = eqx.field(static=True)

    def __call__(self, t, w, args):
        return _variational(t, w, (self.vector_field, args, self.d))


def variational_monodromy(vector_field, y0, args, period, n_periods: int = 1,
                          settings: SolverSettings = SHOOTING_SETTINGS, ode_adjoint=None):
    """d Phi^n / d y0 from the variational equations (state and fundamental matrix
    integrated together). Unlike `jax.jacfwd` of the period map, this is a plain ODE
    solve, so it is differentiable in reverse mode as well (`ode_adjoint`)."""
    d = y0.shape[0]
    t1 = n_periods * jnp.asarray(period, dtype=float)
    w0 = jnp.concatenate([y0, jnp.eye(d).reshape(-1)])
    res = integrate(_Variational(vector_field, d), w0, args, jnp.zeros_like(t1), t1,
                    t1[None], settings, adjoint=ode_adjoint)
    return res.ys[0, d:].reshape(d, d)


def _over_segments(seg, zs, t):
    """`seg(z_i, t_i, t_i+1)` of every segment, stacked. One segment is integrated
    directly, not as a vmap of one: that batches the ODE loop's predicate and carry (a
    select on every step), and the map rows' corrector compiled about 1.4 s longer with
    it (7.7 s against 9.2 s to a first row, 2026-12-02)."""
    if zs.shape[0] == 1:
        return seg(zs[0], t[0], t[1])[None]
    return jax.vmap(seg)(zs, t[:-1], t[1:])


class Shooting(AbstractOrbitMethod):
    """Single (`segments=1`) or multiple shooting with ODE `settings`.

    Pass as `method=` to `periodic_orbit` and `continue_orbits`.
    """

    segments: int = eqx.field(static=True, default=1)
    settings: SolverSettings = eqx.field(static=True, default=SHOOTING_SETTINGS)
    samples_per_period: int = eqx.field(static=True, default=128)

    name = "shooting"
    uses_chord = False  # the Jacobian costs ~ one period map: plain Newton is as cheap
    assembled_jacobian = False  # forward mode through the flow (`residual_and_jacobian`)
    runs_long = True  # ODE solves in every corrector call: the newer fusion emitters

    def __check_init__(self):
        if int(self.segments) < 1:
            raise ValueError(f"Shooting needs segments >= 1, got {self.segments}")

    def _times(self, period, n_periods):
        t_end = n_periods * period
        return t_end * jnp.arange(self.segments + 1) / self.segments

    def init(self, vector_field, y_guess, args, period, n_periods, scale):
        """Unknowns from a state guess at t = 0: the guess flowed to each segment start."""
        z0 = y_guess / scale
        if self.segments == 1:
            return z0
        t = self._times(period, n_periods)
        zs = flow(vector_field, z0, args, scale, t[0], t[-1], t[:-1], self.settings)
        return zs.reshape(-1)

    def init_from_samples(self, ys, scale):
        """Single shooting: the first sample, scaled; multiple shooting: the samples at the
        segment starts where the grid holds them."""
        ys, scale = np.asarray(ys, dtype=float), np.asarray(scale, dtype=float)
        n, m = ys.shape[0], int(self.segments)
        if n % m:
            return None
        return (ys[::n // m] / scale).reshape(-1)

    def residual_and_jacobian(self, vector_field, z, args, period, n_periods, scale):
        """(R(z), dR/dz) by forward mode through the flow (one pass per unknown)."""
        return residual_and_jacobian(
            lambda v, _: self.residual(vector_field, v, args, period, n_periods, scale), z,
            None)

    def residual(self, vector_field, z, args, period, n_periods, scale, ode_adjoint=None):
        adj = ode_adjoint or dfx.ForwardMode()
        d = scale.shape[0]
        zs = z.reshape(self.segments, d)
        t = self._times(period, n_periods)

        def seg(z_i, t0, t1):
            return flow(vector_field, z_i, args, scale, t0, t1, t1[None], self.settings,
                        adj)[0]

        ends = _over_segments(seg, zs, t)
        return (ends - jnp.roll(zs, -1, axis=0)).reshape(-1)

    def initial_state(self, z, period, n_periods, scale):
        return z[: scale.shape[0]] * scale

    def monodromy(self, vector_field, z, args, period, n_periods, scale, jacobian):
        """Scaled monodromy matrix from the Newton matrix (product of the diagonal blocks)."""
        d = scale.shape[0]
        if self.segments == 1:
            return jacobian + jnp.eye(d)
        m = jnp.eye(d)
        for i in range(self.segments):
            m = jacobian[i * d:(i + 1) * d, i * d:(i + 1) * d] @ m
        return m

    def samples(self, vector_field, z, args, period, n_periods, scale, ode_adjoint=None):
        """(ts, ys) on a uniform grid of `samples_per_period * n` points over [0, n T)."""
        adj = ode_adjoint or dfx.ForwardMode()
        d = scale.shape[0]
        k = self.samples_per_period * n_periods
        k_seg = -(-k // self.segments)
        k = k_seg * self.segments
        t_end = n_periods * period
        t = self._times(period, n_periods)
        zs = z.reshape(self.segments, d)

        # A fused loop's samples (the orbit's amplitudes) by its diffrax counterpart, same
        # tolerances: diffrax interpolates the sample times where the fused loop would
        # clip its steps onto them, and its program compiles in a quarter of the time.
        settings = dataclasses.replace(self.settings, solver=FUSED_SOLVERS.get(
            self.settings.solver, self.settings.solver))

        def seg(z_i, t0, t1):
            ts = t0 + (t1 - t0) * jnp.arange(k_seg) / k_seg
            return flow(vector_field, z_i, args, scale, t0, t1, ts, settings, adj)

        ys = _over_segments(seg, zs, t).reshape(k, d) * scale[None, :]
        return t_end * jnp.arange(k) / k, ys

    def error_estimate(self, vector_field, z, args, period, n_periods, scale, residual):
        """Shooting's error is the Newton residual (the ODE error is set by `settings`)."""
        return residual

    def flag_truncation(self, result, error):
        """Shooting has no truncation error of its own (the ODE error is set by
        `settings`)."""
        return result

    def accurate_tol(self) -> float | None:
        return None

    def refine(self, orbit, solve, state_size: int):
        return orbit

    def discretisation(self) -> dict:
        return {"harmonics": None, "segments": int(self.segments)}

    def trajectory(self, vector_field, z, args, period, n_periods, scale, ts,
                   ode_adjoint=None):
        """States at times `ts` in [0, n T] (one integration from the orbit's start)."""
        t_end = n_periods * period
        ys = flow(vector_field, z[: scale.shape[0]], args, scale, jnp.zeros_like(t_end),
                  t_end, ts, self.settings, ode_adjoint or dfx.ForwardMode())
        return ys * scale[None, :]
