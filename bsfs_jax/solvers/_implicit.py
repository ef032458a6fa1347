"""Implicit differentiation of a solution u*(theta) of G(u, theta) = 0.

The solve (Newton, continuation) runs without gradients; its result is then attached to
theta by `attach`, whose primal is the identity on u* and whose derivative is the
implicit function theorem:

    du* = -G_u^{-1} G_theta dtheta                  (forward mode, `ImplicitForward`)
    theta_bar = G_theta^T w,  G_u^T w = -u_bar      (reverse mode, `ImplicitReverse`)

with G_u the Newton matrix at u* (handed over by the solve). Each derivative costs one
linear solve and ONE differentiation of G at the solution: for shooting that is one pass
through one period of the flow, never through the transient, the Newton iterations or
the continuation that found u*.

Which mode is chosen as in diffrax, by a small Module passed as `adjoint=`:
`ImplicitForward()` supports `jax.jvp`/`jax.jacfwd` (the ODE inside G is differentiated
with `diffrax.ForwardMode`); `ImplicitReverse()` supports `jax.grad`/`jax.vjp` (the ODE
with `diffrax.RecursiveCheckpointAdjoint`). JAX cannot give both from one function: a
diffrax solve that supports reverse mode does not support forward mode and vice versa.
"""

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp


class AbstractOrbitAdjoint(eqx.Module):
    """How a periodic orbit (or any implicit solution of the engine) is differentiated."""

    def ode_adjoint(self):
        raise NotImplementedError

    def attach(self, residual, theta, u_star, jacobian):
        raise NotImplementedError


class ImplicitForward(AbstractOrbitAdjoint):
    """Forward-mode implicit differentiation (`jax.jvp`, `jax.jacfwd`): cheapest for few
    inputs and many outputs (identification Jacobians)."""

    def ode_adjoint(self):
        return dfx.ForwardMode()

    def attach(self, residual, theta, u_star, jacobian):
        return _attach_fwd(theta, u_star, jacobian, residual=_explicit(residual, u_star, theta))


class ImplicitReverse(AbstractOrbitAdjoint):
    """Reverse-mode implicit differentiation (`jax.grad`, `jax.vjp`): one adjoint solve for
    the gradient with respect to all parameters (design sensitivities)."""

    def ode_adjoint(self):
        return dfx.RecursiveCheckpointAdjoint()

    def attach(self, residual, theta, u_star, jacobian):
        return _attach_rev(theta, u_star, jacobian, residual=_explicit(residual, u_star, theta))


def _explicit(residual, u_star, theta):
    """`residual` with the arrays it closes over as pytree leaves: a plain function
    (closure) is converted (`eqx.filter_closure_convert`, one more trace of it), an
    `eqx.Module` (the orbit engine's `_Residual`) already carries them. Where the caller is
    jitted and differentiated from outside (`jax.grad` of a jitted function), a closure's
    captured tracers would otherwise leak into the transposed program ("No constant
    handler for type DynamicJaxprTracer")."""
    if isinstance(residual, eqx.Module):
        return residual
    return eqx.filter_closure_convert(residual, u_star, theta)


def _zeros_for_none(primal, tangent):
    return jax.tree_util.tree_map(
        lambda p, t: t if t is not None else (None if p is None else jnp.zeros_like(p)),
        primal, tangent,
        is_leaf=lambda x: x is None)


@eqx.filter_custom_jvp
def _attach_fwd(theta, u_star, jacobian, *, residual):
    return u_star


@_attach_fwd.def_jvp
def _attach_fwd_jvp(primals, tangents, *, residual):
    theta, u_star, jacobian = primals
    t_theta = tangents[0]
    u_star = jax.lax.stop_gradient(u_star)
    if t_theta is None:
        return u_star, jnp.zeros_like(u_star)
    dyn, static = eqx.partition(theta, eqx.is_inexact_array)
    t_dyn = eqx.filter(t_theta, eqx.is_inexact_array)
    t_dyn = _zeros_for_none(dyn, t_dyn)

    def g(d):
        return residual(u_star, eqx.combine(d, static))

    _, g_dot = jax.jvp(g, (dyn,), (t_dyn,))
    du = jnp.linalg.solve(jax.lax.stop_gradient(jacobian), -g_dot)
    return u_star, du


@eqx.filter_custom_vjp
def _attach_rev(theta, u_star, jacobian, *, residual):
    return u_star


@_attach_rev.def_fwd
def _attach_rev_fwd(perturbed, theta, u_star, jacobian, *, residual):
    return u_star, None


@_attach_rev.def_bwd
def _attach_rev_bwd(saved, u_bar, perturbed, theta, u_star, jacobian, *, residual):
    if u_bar is None:
        return jax.tree_util.tree_map(lambda _: None, theta)
    w = jnp.linalg.solve(jacobian.T, -u_bar)
    _, vjp = eqx.filter_vjp(lambda th: residual(u_star, th), theta)
    (theta_bar,) = vjp(w)
    return theta_bar
