"""The floating-point precision the measurement model needs."""

from __future__ import annotations


def require_x64(what: str) -> None:
    """Refuse to run `what` in 32-bit floats: the fit's orbits, gradients and noise levels
    need 64-bit (in float32 the periodic orbits of the through-resonance records fail and the
    fit ends "not converged" for no reason the user can act on)."""
    import jax

    if not jax.config.jax_enable_x64:
        raise RuntimeError(f"{what} needs 64-bit floats: call jax.config.update("
                           "'jax_enable_x64', True) at your program's start, before any "
                           "computation (the bsfs command does this itself).")
