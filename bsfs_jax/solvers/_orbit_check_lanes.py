"""The verifier's orbit checks on the per-lane kernel (`integrate_lanes`).

`check_orbits` (`_orbit_check.py`) vmaps single shooting over the points of a batch, so
its integrations run in lockstep: on a GPU each of their steps is several small kernel
launches, and a call costs the slowest point's steps times a launch-bound step (about
3.5 s for 2048 lanes on an H100). Here the same method runs with every integration on the
kernel, in which each point's loop is its own:

- the variational equations from the sampled state, one column of the monodromy matrix
  per lane: lane (i, j) carries point i's state and the matrix's column j, 2 d components
  (the field and its forward derivative along the column, elementwise like the field
  itself), in the same scaled variables. One lane of d + d^2 components (42 for the ball
  screw) held the whole matrix before; on an H200 XLA had not finished building that
  kernel after 260 s (benchmarks/results/gpu_b1.md, 2026-11-29), while a lane of 12
  components is twice the sweep's own (which compiles in seconds). Each column's lane
  controls its own error and steps, as the whole matrix's lane did;
- chord iterations with that Newton matrix, one kernel call per iteration for every point
  (a point that has converged keeps its state: the iterations of each point are those of
  `check_orbits`);
- the orbit's samples over its n periods.

Every kernel here runs with its stages looped by default (`integrate_lanes(looped=True)`):
on an H200 the whole program (three Triton kernels) then compiled in 18.5 s, against
84.4 s unrolled (benchmarks/results/gpu_b1.md, 2026-11-30), for the same checks.

The results are `check_orbits`' (`OrbitCheck`) to the integrator's error (a run is
restarted where `check_orbits` saves on the way, and the kernel may run the fast forms),
well inside the checks' Newton tolerance. The field is the problem's `component_field`
(`SweepProblem`). Nothing is differentiated through it.
"""

import functools

import jax
import jax.numpy as jnp

from ._lanes import integrate_lanes
from ._orbit_check import CHECK_SETTINGS, OrbitCheck, host_eigvals, state_settings, tightened
from ._results import RESULTS, result_codes

_OK = int(result_codes(RESULTS.successful))
#: Offset of the extra save time after the end of a run, in periods (the kernel records
#: the state at `t_record` and then at least one sample; this one costs a step or two).
_TAIL = 1e-6


def _scaled(field):
    """z' = f(t, z * scale) / scale on components; args = (the field's args, scale, 1 /
    scale): the quotient as a product by the reciprocal computed once, outside the
    kernel (a float64 division is a slow software sequence on a GPU)."""
    def g(t, zs, args):
        inner, scale, inv = args
        ys = tuple(z * s for z, s in zip(zs, scale, strict=True))
        return tuple(v * r for v, r in zip(field(t, ys, inner), inv, strict=True))

    return g


def _tangent(field, d: int):
    """(z, v): z' = g(z), v' = Dg(z) v, on components (one column of the monodromy)."""
    def g(t, ws, args):
        out, tangent = jax.jvp(lambda *zs: field(t, zs, args), tuple(ws[:d]),
                               tuple(ws[d:]))
        return tuple(out) + tuple(tangent)

    return g


#: The columns' lanes run at tolerances this many times tighter than the checks': a
#: column's error control sees the state and that column only, not the whole matrix,
#: and at the checks' own tolerances its monodromy came out 3x further from a reference
#: at rtol 1e-12 than the vmapped checks' (BSFS at 300-3800 Hz, 5000 N: multipliers
#: within 2.7e-6 against 1.1e-6); at a quarter of them 4.4e-7 against 1.1e-6, for
#: about 4^(1/5) = 1.3 times the steps (fifth order) in this one of the checks' runs.
_COLUMN_TIGHTER = 4.0


def _monodromy(g, z0, sargs, t_end, period, settings, fast, block, looped):
    """(Phi^{T_end}(z0), the monodromy matrix (B, d, d), ok (B,)): point i's column j on
    lane i d + j (`_tangent`), the state taken from its column 0's lane."""
    B, d = z0.shape
    rep = lambda a: jnp.repeat(a, d, axis=0)  # noqa: E731 - lane i d + j: point i
    w0 = jnp.concatenate([rep(z0), jnp.tile(jnp.eye(d), (B, 1))], axis=1)
    w, codes = _run_to(_tangent(g, d), w0, jax.tree_util.tree_map(rep, sargs), rep(t_end),
                       rep(period), tightened(settings, _COLUMN_TIGHTER), fast, block,
                       looped)
    w = w.reshape(B, d, 2 * d)
    ok = jnp.all(codes.reshape(B, d) == _OK, axis=1)
    return w[:, 0, :d], jnp.swapaxes(w[:, :, d:], 1, 2), ok


def _run_to(field, y, args, t_end, period, settings, fast, block, looped):
    """States at t_end (per lane) from y at 0, and the lanes' result codes."""
    start, _, _, codes, _ = integrate_lanes(
        field, y, args, t_end, _TAIL * period, n_samples=1, samples_per_period=1,
        rtol=settings.rtol, atol=settings.atol, max_steps=settings.max_steps, block=block,
        fast=fast, looped=looped)
    return start, codes


@functools.partial(jax.jit, static_argnames=("field", "setup", "max_steps", "max_period",
                                             "spp", "settings", "fast", "block",
                                             "looped"))
def _check(field, setup, data, values, y_guess, scale, n, tol, *, max_steps, max_period,
           spp, settings, fast, block, looped):
    B, d = y_guess.shape
    args, period = jax.vmap(lambda v: setup(data, v))(values)
    period = jnp.asarray(period, dtype=float)
    nf = n.astype(float)
    t_end = nf * period
    eye = jnp.eye(d)
    eyes = jnp.broadcast_to(eye, (B, d, d))
    sargs = (args, scale, 1.0 / scale)
    g = _scaled(field)
    sset = state_settings(settings)  # the state-only runs' tolerances (`STATE_TIGHTER`)
    z0 = y_guess / scale
    z_end, phi, ok0 = _monodromy(g, z0, sargs, t_end, period, settings, fast, block, looped)
    f0 = jnp.where(ok0[:, None], z_end - z0, jnp.nan)
    j0 = phi - eyes
    j0 = jnp.where(ok0[:, None, None], j0, jnp.nan)
    ok0 = ok0 & jnp.all(jnp.isfinite(f0), axis=1) & jnp.all(jnp.isfinite(j0), axis=(1, 2))
    lu = jax.vmap(jax.scipy.linalg.lu_factor)(jnp.where(ok0[:, None, None], j0, eyes))

    def pending(z, f, k, ok):
        big = jnp.max(jnp.abs(f), axis=1) > tol * jnp.maximum(1.0, jnp.max(jnp.abs(z), axis=1))
        return (k < max_steps) & big & ok

    def cond(c):
        return jnp.any(pending(*c))

    def body(c):
        z, f, k, ok = c
        go = pending(z, f, k, ok)
        z_try = z - jax.vmap(jax.scipy.linalg.lu_solve)(lu, f)
        y, st = _run_to(g, jnp.where(go[:, None], z_try, z), sargs, t_end, period, sset,
                        fast, block, looped)
        f_try = jnp.where((st == _OK)[:, None], y - z_try, jnp.nan)
        keep = lambda new, old: jnp.where(go[:, None], new, old)  # noqa: E731
        ok_new = jnp.where(go, jnp.all(jnp.isfinite(f_try), axis=1), ok)
        return keep(z_try, z), keep(f_try, f), k + go.astype(k.dtype), ok_new

    z, f, k, ok = jax.lax.while_loop(cond, body, (z0, f0, jnp.zeros(B, int), ok0))
    res_norm = jnp.max(jnp.abs(f), axis=1)
    converged = ok & (res_norm <= tol * jnp.maximum(1.0, jnp.max(jnp.abs(z), axis=1)))
    mu = host_eigvals(j0 + eyes)
    mu = jnp.take_along_axis(mu, jnp.argsort(-jnp.abs(mu), axis=1), axis=1)
    # The orbit's samples at j T / spp, j = 1..n spp: the first saved at the end of the
    # run, the others after it (a lane stops at its own n T, as `check_orbits` does; the
    # samples past it are undefined and dropped below).
    m = max_period * spp
    first, rest, _, st, _ = integrate_lanes(
        g, z, sargs, period / spp, period, n_samples=m - 1, samples_per_period=spp,
        rtol=sset.rtol, atol=sset.atol, max_steps=sset.max_steps, block=block,
        fast=fast, lane_samples=jnp.maximum(n * spp - 1, 1), looped=looped)
    ys = jnp.concatenate([first[:, None], rest], axis=1) * scale[:, None, :]
    j = jnp.arange(1, m + 1, dtype=float)
    valid = (j[None] <= nf[:, None] * spp) & (st == _OK)[:, None]
    samples = jnp.where(valid[..., None], ys, jnp.nan)
    # Stroboscopic points o_1..o_max; past n T they repeat the state at n T.
    strobe = samples[:, spp - 1::spp]
    last = jnp.take_along_axis(strobe, (n - 1)[:, None, None], axis=1)
    strobe = jnp.where((jnp.arange(1, max_period + 1)[None] <= n[:, None])[..., None],
                       strobe, last)
    converged = converged & (st == _OK)
    return OrbitCheck(z * scale, converged, res_norm, mu, strobe, samples, k,
                      jnp.max(jnp.abs(z - z0), axis=1), j0 + eyes)


def check_orbits_lanes(component_field, setup, data, values, y_guess, scale, n, *,
                       tol: float = 1e-6, max_steps: int = 16, max_period: int = 16,
                       samples_per_period: int = 32, settings=CHECK_SETTINGS,
                       fast: bool = False, block: int = 32,
                       looped: bool = True) -> OrbitCheck:
    """`check_orbits` with every integration on the per-lane kernel (module docstring).

    `component_field(t, ys, args)`: the system on a tuple of state components (the
    `SweepProblem.component_field`, elementwise); `setup(data, value) -> (args, period)`
    as for `check_orbits`, its args' leaves per point. `settings`: the checks' rtol, atol
    and max_steps (a `SolverSettings`); `fast`, `block`, `looped`: as `integrate_lanes`.
    One program per batch layout; values, states, scales and periods are traced.
    """
    return _check(component_field, setup, data, jnp.asarray(values, dtype=float),
                  jnp.asarray(y_guess, dtype=float), jnp.asarray(scale, dtype=float),
                  jnp.asarray(n, dtype=int), jnp.asarray(tol, dtype=float),
                  max_steps=int(max_steps), max_period=int(max_period),
                  spp=int(samples_per_period), settings=settings, fast=bool(fast),
                  block=int(block), looped=bool(looped))
