"""Batched periodic-orbit checks at sampled states: shooting with a traced period count.

For each (point, n) pair, Newton's method solves Phi^{nT}(z) - z = 0 in scaled variables
(`Scaled`) from a sampled stroboscopic state. This is single shooting like the orbit
engine's (`periodic_orbit` with `Shooting`: the same scaled field, the same variational
equations), specialised for checking many sampled states at once, as the sweep verifier
(`bsfs_jax.analysis`) does at every point: n is a *traced* integer, so one compiled
function serves every period n <= max_period and every point (vmapped), and the Newton
matrix comes from the variational equations (`_shooting._Variational`) integrated by the
fast forward-only Dormand-Prince loop, not from forward-mode AD through diffrax (about ten
times cheaper per step in a vmapped batch here). Nothing is differentiated through it.
It returns the Floquet multipliers (eigenvalues of the monodromy matrix), the orbit's
stroboscopic points o_1..o_max (to find the minimal period) and its samples over n T
(for the amplitude).
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._programs import cached_jit, prefetch_jit, settle
from ._integrate import SolverSettings, integrate
from ._results import RESULTS
from ._shooting import Scaled, _Variational

#: The state-only runs (chord steps, the orbit's samples) run at tolerances this many
#: times tighter than the checks' own: the variational run, whose error control covers
#: the monodromy matrix too, takes about twice the steps and so integrates the state far
#: more accurately than a state-only run at the same tolerances. On B1's 620 Hz point
#: (5000 N) a state-only period at the checks' rtol 1e-8 was 2.9e-6 (scaled) from a
#: reference at rtol 1e-12, above the Newton tolerance 1e-6, while the variational run's
#: state was within 1e-8: the chord steps then chased a residual the two runs disagree
#: on, and from the orbit itself stalled at 2.7e-6 for 16 iterations (no verdict, more
#: candidate periods, a settle block). At a quarter of the tolerances: 9.9e-8, in 465
#: steps against 358 (the variational run: 835).
STATE_TIGHTER = 4.0


def tightened(settings: SolverSettings, factor: float) -> SolverSettings:
    """`settings` with rtol and atol divided by `factor`."""
    return dataclasses.replace(settings, rtol=settings.rtol / factor,
                               atol=settings.atol / factor)


def state_settings(settings: SolverSettings) -> SolverSettings:
    """The checks' settings for their state-only runs (`STATE_TIGHTER`)."""
    return tightened(settings, STATE_TIGHTER)


def host_eigvals(matrices):
    """Eigenvalues of a batch of small square matrices (..., d, d), by LAPACK on the host.

    On a GPU jax's default for a general matrix is cuSOLVER's geev where the CUDA version
    has it, and jaxlib runs its unbatched solvers one matrix at a time: for the checks'
    2048 monodromy matrices of 6 x 6 likely of the order of a second (a call of the checks
    cost at least 1.0 s on an H200 with ~0.1 s of integration; not yet confirmed), while
    the host's LAPACK takes milliseconds. On a CPU this is `jnp.linalg.eigvals` exactly.
    Not for differentiated code (the batches here are verdicts, not gradients)."""
    from jax.lax import linalg

    return linalg.eig(matrices, compute_left_eigenvectors=False,
                      compute_right_eigenvectors=False,
                      implementation=linalg.EigImplementation.LAPACK)[0]


#: Orbit settings of the verifier: Newton reaches 1e-6 (relative, scaled variables; the
#: orbit to ~1e-6 of its amplitude, the multipliers to ~1e-6; its state-only runs at a
#: quarter of these tolerances, `STATE_TIGHTER`) and is cheap enough to run at every
#: sweep point.
CHECK_SETTINGS = SolverSettings(rtol=1e-8, atol=1e-10, solver="dopri5-fused",
                                max_steps=2_000_000)


class OrbitCheck(eqx.Module):
    """Batched outcome (leading axis B) of `check_orbits`.

    `state` (B, d): the orbit's state at t = 0 (mod T) in the system's units;
    `converged` (B,); `residual` (B,): max-norm of the scaled residual; `multipliers`
    (B, d) complex, largest modulus first; `strobe` (B, max_period, d): the orbit's states
    at t = j T, j = 1..max_period (only j <= n are meaningful; later ones repeat t = n T);
    `samples` (B, max_period * spp, d): states at t = j T / spp up to n T (NaN after);
    `steps` (B,): chord iterations (at least one runs, and gives the samples; it is not
    counted where the start was an orbit to the tolerance already); `jac_distance` (B,):
    scaled distance between the orbit and the state where the monodromy matrix (and so
    `multipliers`) was evaluated;
    `monodromy` (B, d, d): that matrix, in the variables divided by `scale`.
    """

    state: jax.Array
    converged: jax.Array
    residual: jax.Array
    multipliers: jax.Array
    strobe: jax.Array
    samples: jax.Array
    steps: jax.Array
    jac_distance: jax.Array
    monodromy: jax.Array


def _check_one(vector_field, setup, data, value, y_guess, scale, n, tol, max_steps,
               max_period, spp, settings):
    args, period = setup(data, value)
    period = jnp.asarray(period, dtype=float)
    field = Scaled(vector_field)
    d = y_guess.shape[0]
    var = _Variational(field, d)
    nf = jnp.asarray(n, dtype=float)
    t_end = nf * period
    eye = jnp.eye(d)

    def phi(z):
        """(Phi^{nT}(z) - z, dPhi^{nT}/dz - I) from the variational equations."""
        w0 = jnp.concatenate([z, eye.reshape(-1)])
        res = integrate(var, w0, (args, scale), 0.0, t_end, t_end[None], settings,
                        throw=False)
        w = res.ys[-1]
        return w[:d] - z, w[d:].reshape(d, d) - eye

    z0 = y_guess / scale
    f0, j0 = phi(z0)
    ok0 = jnp.all(jnp.isfinite(f0)) & jnp.all(jnp.isfinite(j0))

    state_run = state_settings(settings)  # the chord steps' and samples' runs
    j = jnp.arange(1, max_period * spp + 1, dtype=float)
    ts = jnp.minimum(j * period / spp, t_end)

    def run(z):
        """(Phi^{nT}(z) - z, the states at ts, result): one state-only run, sampled, so
        that the chord steps and the orbit's samples share one integration loop in the
        program (the last chord step's run gives the samples)."""
        res = integrate(field, z, (args, scale), 0.0, t_end, ts, state_run, throw=False)
        return res.ys[-1] - z, res.ys, res.result

    def within(f, z):
        return jnp.max(jnp.abs(f)) <= tol * jnp.maximum(1.0, jnp.max(jnp.abs(z)))

    def cond(c):
        z, f, k, ok = c[:4]
        # At least one chord step: its run gives the samples at the returned state.
        return (k == 0) | ((k < max_steps) & ~within(f, z) & ok)

    # Chord iterations with the Newton matrix of the sampled state: each costs one period
    # map of the state only (the variational equations cost several times more, and
    # under vmap a switch back to full Newton steps would be paid by every lane). From a
    # sampled state near a stable orbit they converge at once; the multipliers are then
    # those of the matrix at the sampled state, `jac_distance` away from the orbit (the
    # caller re-evaluates them at the orbit where that distance is not small).
    lu = jax.scipy.linalg.lu_factor(j0)

    def body(c):
        z, f, k, _, _, _ = c
        z_new = z - jax.scipy.linalg.lu_solve(lu, f)
        f_new, ys, result = run(z_new)
        return z_new, f_new, k + 1, jnp.all(jnp.isfinite(f_new)), ys, result

    ys0 = jnp.zeros((ts.shape[0], d), dtype=z0.dtype)
    z, f, k, ok, ys, result = jax.lax.while_loop(
        cond, body, (z0, f0, jnp.asarray(0), ok0, ys0, RESULTS.successful))
    jac = j0
    res_norm = jnp.max(jnp.abs(f))
    converged = ok & within(f, z)
    mu = host_eigvals(jac + eye)
    mu = mu[jnp.argsort(-jnp.abs(mu))]
    ys = ys * scale[None, :]
    valid = (j <= nf * spp) & (result == RESULTS.successful)
    samples = jnp.where(valid[:, None], ys, jnp.nan)
    strobe = ys[spp - 1::spp]
    converged = converged & (result == RESULTS.successful)
    # Chord steps the convergence needed: the one run that only samples an orbit the
    # start already was (to the tolerance) is not counted.
    start_ok = ok0 & within(f0, z0)
    return OrbitCheck(z * scale, converged, res_norm, mu, strobe, samples,
                      k - start_ok.astype(k.dtype),
                      jnp.max(jnp.abs(z - z0)), jac + eye)


# XLA's backend level 1 (`cached_jit`'s fast_compile): the README's 240-point verified
# sweep 1.4 s sooner cold (20.1 -> 18.5-18.7 s on a loaded 2-core machine), the same 240
# labels, amplitudes within 2e-7 and multipliers within 1e-8 (the check's Newton stops at
# a residual of about 2e-7).
@cached_jit(fast_compile=True)
def _check_batch(vector_field, setup, data, values, y_guess, scale, n, tol, max_steps,
                 max_period, spp, settings):
    def one(v, y, s, nn):
        return _check_one(vector_field, setup, data, v, y, s, nn, tol, max_steps,
                          max_period, spp, settings)

    out = jax.vmap(one)(values, y_guess, scale, n)
    # A tuple of arrays, not the Module: the program is kept across processes
    # (`cached_jit`, `jax.export` writes tuples of arrays).
    return tuple(getattr(out, f.name) for f in dataclasses.fields(OrbitCheck))


_PREFETCHED: dict = {}  # ids of (vector field, setup), batch, states -> future program


def _args(values, y_guess, scale, n, tol, max_steps, max_period, spp):
    return (jnp.asarray(values, dtype=float), jnp.asarray(y_guess, dtype=float),
            jnp.asarray(scale, dtype=float), jnp.asarray(n, dtype=int), float(tol),
            int(max_steps), int(max_period), int(spp))


def prefetch_check_orbits(vector_field, setup, data, batch: int, n_states: int, *,
                          tol: float = 1e-6, max_steps: int = 16, max_period: int = 16,
                          samples_per_period: int = 32,
                          settings: SolverSettings = CHECK_SETTINGS) -> None:
    """Start compiling `check_orbits`' program for batches of `batch` points of
    `n_states` states in the background (`bsfs_jax._programs.prefetch_jit`): the sweep
    verifier asks for it before its sweep integrates, and `check_orbits` waits for it."""
    key = (id(vector_field), id(setup), int(batch), int(n_states))
    if key in _PREFETCHED:
        return
    dummy = _args(np.ones(batch), np.ones((batch, n_states)), np.ones((batch, n_states)),
                  np.ones(batch, int), tol, max_steps, max_period, samples_per_period)
    args = (vector_field, setup, data, *dummy, settings)
    # A kept program (a vector field of bsfs_jax) waits in `cached_jit`'s own queue (and
    # is not prefetched again once loaded or pending); any other is compiled by jit and
    # waited for here (`check_orbits`).
    if _check_batch.keeps(*args):
        _check_batch.prefetch(*args)
    else:
        _PREFETCHED[key] = prefetch_jit(_check_batch.plain, *args)


def check_orbits(vector_field, setup, data, values, y_guess, scale, n, *, tol: float = 1e-6,
                 max_steps: int = 16, max_period: int = 16, samples_per_period: int = 32,
                 settings: SolverSettings = CHECK_SETTINGS) -> OrbitCheck:
    """Look for orbits of period n_i T from the states `y_guess[i]` at parameter values[i].

    `vector_field(t, y, args)` is the system; `setup(data, value)` gives its `(args,
    period)` at one parameter value (`data`: a pytree of arrays, traced); `scale` (B, d)
    the per-coordinate scale of the unknowns; `n` (B,) integer periods in 1..max_period.
    Compiled once per (vector field, setup, data structure, max_period,
    samples_per_period, settings): values, states, scales and periods are traced. Waits
    for a prefetch of the same batch layout (`prefetch_check_orbits`) rather than compiling
    the program a second time.
    """
    args = _args(values, y_guess, scale, n, tol, max_steps, max_period, samples_per_period)
    # a prefetched program of this layout is then found in jit's cache
    settle(_PREFETCHED.pop((id(vector_field), id(setup), *np.shape(y_guess)), None))
    return OrbitCheck(*_check_batch(vector_field, setup, data, *args, settings))
