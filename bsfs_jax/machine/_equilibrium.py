"""Static equilibrium with thermal offsets, linearised modes and the linear FRF."""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._numerics import cofactors_3x3
from ..model import restoring_forces
from ._system_arg import as_system

_X_SCALE = 1e-6  # solve in micrometres: well scaled for Newton
_F_SCALE = 1e3  # and kilonewtons
_MAX_STEPS = 100


def _tolerance() -> float:
    """Newton's rtol = atol [um, kN]: 1e-12 in 64-bit floats; in 32-bit 1e3 ulps (1.2e-4),
    above the round-off of the preloaded pairs' forces, which cancel at equilibrium."""
    return max(1e-12, 1e3 * float(jnp.finfo(jnp.result_type(float)).eps))


def _equilibrium_residual(z, args):
    system, p0 = args
    f = restoring_forces(system, z * _X_SCALE, jnp.zeros(3))
    return (f - jnp.stack([0.0, 0.0, p0])) / _F_SCALE


def equilibrium(model, static_force_n=0.0, *, throw: bool = True):
    """Static displacements (x_b, x_s, x_n) [m] under a constant axial force on the nut.

    Solves the restoring forces of Eq. 31 = (0, 0, P0) by Newton (optimistix), with the
    thermal offsets in place. With P0 = 0 and symmetric pairs this is x = 0.

    **Arguments:**
    - `model`: `BallScrewParams` or a built `System`.
    - `static_force_n`: the constant axial force P0 on the nut [N].
    - `throw`: raise `SolverError` (naming the cause) when the Newton solve fails and the
      result is concrete. Under jit/vmap nothing is raised and the last iterate is
      returned.
    """
    system = as_system(model)
    if isinstance(static_force_n, (int, float)) and static_force_n == 0.0:
        # Unforced, the equilibrium is x = 0 to the bit: both halves of each preloaded pair
        # share one reach (one thermal offset), so their forces cancel exactly at u = 0, and
        # the screw spring is unloaded. Newton would return its start, zero, with zero
        # derivatives; skipping it spares every caller that asks for the unforced modes the
        # Newton loop's compilation (most of `bsfs modes` and `bsfs simulate`'s report).
        return jnp.zeros(3)
    import optimistix as optx  # here: `bsfs modes` and the unforced callers never load it

    tol = _tolerance()
    # The system travels in `args`, not in a closure: optimistix compiles its solve once
    # per function, and a new closure per call compiled it again on every eager call (24
    # times, 8.8 s, in one forecast).
    sol = optx.root_find(_equilibrium_residual, optx.Newton(rtol=tol, atol=tol),
                         jnp.zeros(3), args=(system, jnp.asarray(static_force_n, dtype=float)),
                         throw=False, max_steps=_MAX_STEPS)
    if throw:
        _check(sol, static_force_n)
    return sol.value * _X_SCALE


def _check(sol, static_force_n):
    """Raise `SolverError` for a concrete, failed Newton solve of `equilibrium`."""
    from ..solvers import RESULTS, SolverError, is_concrete, result_message

    if not is_concrete((sol.result, sol.value)):
        return
    result = RESULTS.promote(sol.result)
    finite = jnp.all(jnp.isfinite(sol.value))
    failed = RESULTS.where(result == RESULTS.singular, RESULTS.singular_jacobian,
                           RESULTS.newton_failed)
    failed = RESULTS.where(finite, failed, RESULTS.non_finite)
    result = RESULTS.where((result == RESULTS.successful) & finite, RESULTS.successful, failed)
    if not bool(result == RESULTS.successful):
        try:
            p0 = f"{float(static_force_n):g} N"
        except (TypeError, ValueError):
            p0 = "the given force"
        raise SolverError(
            f"static equilibrium under P0 = {p0} failed: {result_message(result)}. Newton "
            f"settings: rtol = atol = {_tolerance():g}, max_steps={_MAX_STEPS}.")


class Modes(eqx.Module):
    """Linearised modal data about the static equilibrium.

    - `frequencies_hz` (3,), ascending undamped natural frequencies;
    - `shapes` (3, 3): column i is mode i, mass-normalised (phi^T M phi = 1);
    - `damping_ratios` (3,): modal approximation phi^T C phi / (2 omega);
    - `stiffness` (3, 3) [N/m], `damping` (3, 3) [N s/m], `mass` (3,) [kg];
    - `equilibrium` (3,) [m].
    """

    frequencies_hz: jax.Array
    shapes: jax.Array
    damping_ratios: jax.Array
    stiffness: jax.Array
    damping: jax.Array
    mass: jax.Array
    equilibrium: jax.Array

    @classmethod
    def from_matrices(cls, k, c, m, x_eq) -> "Modes":
        """Modes of the tangent stiffness `k`, damping `c` and masses `m` (3,) about `x_eq`
        (the undamped problem, mass-normalised shapes, modal damping ratios)."""
        inv_sqrt_m = 1.0 / jnp.sqrt(m)
        k_sym = k * inv_sqrt_m[:, None] * inv_sqrt_m[None, :]
        k_sym = 0.5 * (k_sym + k_sym.T)
        lam, vecs = jnp.linalg.eigh(k_sym)
        omega = jnp.sqrt(jnp.abs(lam))
        shapes = vecs * inv_sqrt_m[:, None]
        # Fix the sign: largest component of each shape positive (deterministic output).
        idx = jnp.argmax(jnp.abs(shapes), axis=0)
        shapes = shapes * jnp.sign(shapes[idx, jnp.arange(3)])[None, :]
        zeta = jnp.einsum("ji,jk,ki->i", shapes, c, shapes) / (2.0 * omega)
        return cls(omega / (2 * jnp.pi), shapes, zeta, k, c, m, x_eq)

    @property
    def static_stiffness(self):
        """Axial stiffness at the nut, P / x_n [N/m] (the drive's static stiffness):
        1 / (K^-1)_22 = det K / C_22, with C the cofactors (closed form, no LU)."""
        c, det = cofactors_3x3(self.stiffness)
        return det / c[2, 2]


def tangent_matrices(model, x=None, v=None):
    """(K, C, m): the restoring forces' tangent stiffness dF/dx and damping dF/dv at the
    state (x, v) (default: x = 0, v = 0), and the masses m (vector) [N/m, N s/m, kg].

    The one linearisation of the model: `linearise` takes it at the static equilibrium;
    identification's receptance and harmonic-balance correction at x = 0 (the unforced
    equilibrium: both halves of each preloaded pair carry the same thermal offset, so
    F(0) = 0). Traceable; no Newton solve.
    """
    system = as_system(model)
    x = jnp.zeros(3) if x is None else jnp.asarray(x, dtype=float)
    v = jnp.zeros(3) if v is None else jnp.asarray(v, dtype=float)
    k = jax.jacfwd(lambda xx: restoring_forces(system, xx, v))(x)
    c = jax.jacfwd(lambda vv: restoring_forces(system, x, vv))(v)
    return k, c, system.mass


def linearise(model, static_force_n=0.0, *, throw: bool = True):
    """(K, C, M, x_eq): tangent stiffness and damping matrices about the equilibrium
    (`tangent_matrices` there; M is the vector of masses).

    `throw` as in `equilibrium`.
    """
    system = as_system(model)
    x_eq = equilibrium(system, static_force_n, throw=throw)
    return (*_tangent_matrices(system, x_eq), x_eq)


# Called eagerly (a report's modes, a design check, a plan), the linearisation and the modal
# analysis ran op by op: about 50 small compiled programs. As programs of their own they
# compile once; under an outer jit they are inlined (the system: `as_system`).
_tangent_matrices = eqx.filter_jit(tangent_matrices)


@eqx.filter_jit
def _modes_at(system, x_eq) -> "Modes":
    return Modes.from_matrices(*tangent_matrices(system, x_eq), x_eq)


def modes(model, static_force_n=0.0, *, throw: bool = True) -> Modes:
    """Natural frequencies and mode shapes linearised about the static equilibrium.

    `throw` as in `equilibrium`.
    """
    system = as_system(model)
    return _modes_at(system, equilibrium(system, static_force_n, throw=throw))


def linear_frf(model, frequencies_hz, static_force_n=0.0, *, throw: bool = True):
    """Complex receptance x_j / P [m/N] of the linearised system, shape (len(f), 3).

    H(w) = (K - w^2 M + i w C)^(-1) e_nut; the small-force limit of Eq. 31. `throw` as in
    `equilibrium`.
    """
    k, c, m, _ = linearise(model, static_force_n, throw=throw)
    omega = 2 * jnp.pi * jnp.atleast_1d(jnp.asarray(frequencies_hz, dtype=float))
    rhs = jnp.array([0.0, 0.0, 1.0], dtype=complex)

    def one(w):
        dyn = k - w**2 * jnp.diag(m) + 1j * w * c
        return jnp.linalg.solve(dyn.astype(complex), rhs)

    return jax.vmap(one)(omega)


JOINTS = ("bearing", "nut")


def joint_windows(system, x_eq):
    """{joint: margin [m]}: how far each joint's relative displacement (bearing: x_b; nut:
    x_n - x_s) may move from the equilibrium `x_eq` (either way) before a side's contact
    deformation reaches zero (`physics.contact_deformations`), from the pair's geometry."""
    out = {}
    for joint, pair, u_eq in (("bearing", system.bearing, x_eq[0]),
                              ("nut", system.nut, x_eq[2] - x_eq[1])):
        root = jnp.sqrt(pair.reach**2 - pair.radial_sq)
        u_hi = pair.cos_helix * (pair.axial - root)
        out[joint] = jnp.minimum(u_hi - u_eq, u_eq + u_hi)
    return out


def linear_liftoff_force(model, frequencies_hz):
    """(len(JOINTS),) [N]: per joint the smallest sinusoidal force amplitude on the nut at
    which the linearised response's joint displacement reaches its contact window at one
    of `frequencies_hz` (a grid over a band: the largest joint receptance there). Above it
    the joint opens in the linear model; the nonlinear orbits open a few per cent lower
    near a resonance. Traceable."""
    system = as_system(model)
    k, c, m, x_eq = linearise(system)
    win = joint_windows(system, x_eq)
    h = linear_frf(system, frequencies_hz)
    rec = {"bearing": jnp.max(jnp.abs(h[:, 0])), "nut": jnp.max(jnp.abs(h[:, 2] - h[:, 1]))}
    return jnp.stack([win[j] / rec[j] for j in JOINTS])
