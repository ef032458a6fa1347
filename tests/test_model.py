"""The 3-DOF model (Eq. 31): joint forces, symmetry, potential and energy conservation."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import bsfs_jax as bsfs
from bsfs_jax import physics
from bsfs_jax.model import accelerations, restoring_forces
from bsfs_jax.solvers import SolverSettings, integrate

from .helpers import relative_error
from .reference_model import ReferenceBSFS


@pytest.fixture(scope="module")
def system():
    """Default preset, thermal on (equal, non-zero offsets on both halves of each pair)."""
    return bsfs.build_system(bsfs.preset())


def _contact_loss_u(pair):
    a, a0, b, cl, d = (float(x) for x in (pair.a, pair.a0, pair.contact_angle,
                                            pair.cos_helix, pair.offset))
    return cl * (a * np.sin(b) - np.sqrt((a0 + d) ** 2 - (a * np.cos(b)) ** 2))


def test_joint_forces_zero_at_rest(system):
    f = bsfs.joint_forces(system, jnp.zeros(3))
    assert np.all(np.asarray(f) == 0.0)
    np.testing.assert_allclose(bsfs.equilibrium(system), 0.0, atol=1e-15)
    # The unforced equilibrium skips Newton (x = 0 by the symmetry above); a traced zero
    # force takes the Newton path, which must return the same point.
    np.testing.assert_array_equal(np.asarray(_equilibrium(system, jnp.array(0.0))), 0.0)


def test_joint_forces_odd(system):
    key = jax.random.PRNGKey(0)
    u_n, u_b = _contact_loss_u(system.nut), _contact_loss_u(system.bearing)
    # Displacements up to 3x the contact-loss point of either joint (both one-sided).
    scale = jnp.array([u_b, u_n, u_n])[None, :]
    x = jax.random.uniform(key, (200, 3), minval=-3.0, maxval=3.0) * scale
    f_pos = bsfs.joint_forces(system, x)
    f_neg = bsfs.joint_forces(system, -x)
    np.testing.assert_allclose(f_neg, -f_pos, rtol=1e-12, atol=1e-12)
    # The vector field is odd in the state when unforced.
    force = jnp.zeros(200)
    v = 0.01 * x / u_n
    np.testing.assert_allclose(accelerations(system, -x, -v, force),
                               -accelerations(system, x, v, force), rtol=1e-12, atol=1e-6)


_equilibrium = eqx.filter_jit(bsfs.equilibrium)


@pytest.mark.parametrize("force", [100.0, 5000.0, 20000.0])
def test_static_equilibrium(system, force):
    """Under a static nut force P every joint (in series) carries exactly P."""
    x = _equilibrium(system, jnp.array(force, dtype=jnp.float64))
    np.testing.assert_allclose(restoring_forces(system, x, jnp.zeros(3)), [0.0, 0.0, force],
                               atol=1e-9 * force)
    np.testing.assert_allclose(bsfs.joint_forces(system, x), [force] * 3, rtol=1e-9)
    assert np.all(np.diff(np.asarray(x)) > 0)  # each joint stretches in the load direction
    _, d_minus = physics.contact_deformations(x[2] - x[1], system.nut)
    assert (float(d_minus) < 0.0) == (force > 4500.0)  # one nut half unloaded beyond ~4.35 kN


def test_against_reference_force_law(system):
    """Joint forces of the library against the NumPy oracle's (K and offsets as inputs)."""
    params = bsfs.preset()
    ref = ReferenceBSFS(params.to_dict(), nut_k=float(system.nut.hertz_k),
                        bearing_k=float(system.bearing.hertz_k),
                        nut_offset=float(system.nut.offset),
                        bearing_offset=float(system.bearing.offset))
    np.testing.assert_allclose(ref.k_s, float(system.screw_stiffness), rtol=1e-12)
    u = np.linspace(-30e-6, 30e-6, 121)
    np.testing.assert_allclose(physics.pair_force(jnp.asarray(u), system.nut),
                               ref.nut.force(u), rtol=1e-11, atol=1e-9)
    np.testing.assert_allclose(physics.pair_force(jnp.asarray(u), system.bearing),
                               ref.bearing.force(u), rtol=1e-11, atol=1e-9)
    x = np.array([3e-6, -2e-6, 9e-6])
    v = np.array([0.01, -0.02, 0.03])
    np.testing.assert_allclose(restoring_forces(system, jnp.asarray(x), jnp.asarray(v)),
                               ref.restoring(x, v), rtol=1e-11)


def test_potential_is_exact(system):
    """-grad(elastic energy) equals the elastic restoring forces, also past contact loss."""
    u_n = _contact_loss_u(system.nut)

    def elastic(x):
        return bsfs.mechanical_energy(system, jnp.concatenate([x, jnp.zeros(3)]))

    for x in ([1e-6, -1e-6, 2e-6], [0.0, 0.0, 2 * u_n], [-2 * u_n, 0.0, -3 * u_n]):
        x = jnp.asarray(x)
        np.testing.assert_allclose(jax.grad(elastic)(x),
                                   restoring_forces(system, x, jnp.zeros(3)),
                                   rtol=1e-10, atol=1e-9)


def test_vector_field_derivatives_finite_at_contact_loss(system):
    u_star = _contact_loss_u(system.nut)
    forcing = bsfs.Sinusoid(100.0, 500.0)

    @jax.jit
    def derivatives(y, system):
        field = lambda y, s: bsfs.vector_field(0.0, y, (s, forcing))
        return (jax.jacfwd(field)(y, system),
                jax.hessian(lambda y: field(y, system)[5])(y),
                jax.grad(lambda s: field(y, s)[5])(system))

    for shift in (-1e-9, 0.0, 1e-9):
        y = jnp.array([0.0, 0.0, u_star + shift, 0.0, 0.0, 0.0])
        for leaf in jax.tree_util.tree_leaves(derivatives(y, system)):
            assert np.all(np.isfinite(np.asarray(leaf))), shift


# --------------------------------------------------------------------------------------
# 4. Energy conservation without damping and forcing
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def undamped():
    params = bsfs.preset()
    for key in ("bearing", "screw", "nut"):
        params = params.replace(f"damping.{key}_n_s_per_m", 0.0)
    return bsfs.build_system(params)


_ENERGY_T1 = 10e-3  # ~12 periods of the first mode
_ENERGY_TS = jnp.linspace(0.0, _ENERGY_T1, 401)
# The drift this test sees is the integrator's own error (it scales with rtol: about 1e-8
# at rtol 1e-12, 7e-10 at 1e-13, 6e-11 at 1e-14, the contact-loss kinks dominating), so at
# rtol 1e-12 any rounding-level change of the force law moved it across the 1e-8 bound.
# At 1e-13 the bound checks the force law's consistency with its potential, with margin.
_ENERGY_SETTINGS = SolverSettings(rtol=1e-13, atol=1e-18, max_steps=400_000)


@eqx.filter_jit
def _free_run(system, y0):
    forcing = bsfs.Sinusoid(0.0, 500.0)
    return integrate(bsfs.vector_field, y0, (system, forcing), 0.0, _ENERGY_T1, _ENERGY_TS,
                     _ENERGY_SETTINGS)


@pytest.mark.parametrize("nut_stretch", [0.2, 3.0])  # x contact-loss displacement
def test_energy_conservation(undamped, nut_stretch):
    u_star = _contact_loss_u(undamped.nut)
    y0 = jnp.array([0.0, 0.0, nut_stretch * u_star, 0.0, 0.0, 0.0])
    res = _free_run(undamped, y0)
    assert bool(res.ok)
    # The potential includes the energy stored by the preload; measure the drift against
    # the vibration energy above that rest level, not against the (larger) total.
    rest = float(bsfs.mechanical_energy(undamped, jnp.zeros(6)))
    energy = np.asarray(bsfs.mechanical_energy(undamped, res.ys)) - rest
    energy0 = float(bsfs.mechanical_energy(undamped, y0)) - rest
    assert energy0 > 0
    drift = np.max(np.abs(energy - energy0)) / energy0
    assert drift < 1e-8, drift
    u = np.asarray(res.ys[:, 2] - res.ys[:, 1])
    if nut_stretch > 1:  # the run really loses contact on both sides of the nut
        assert u.max() > u_star and u.min() < -u_star
    else:
        assert np.abs(u).max() < u_star
    # Damping dissipates: the same run with the default damping loses energy.
    damped = eqx.tree_at(lambda s: s.damping, undamped, bsfs.build_system(bsfs.preset()).damping)
    res_d = _free_run(damped, y0)
    energy_d = np.asarray(bsfs.mechanical_energy(damped, res_d.ys)) - rest
    assert energy_d[-1] < 0.9 * energy0
    assert np.all(np.diff(energy_d) <= 1e-10 * energy0)
    assert relative_error(energy_d[:1], [energy0]) < 1e-14
