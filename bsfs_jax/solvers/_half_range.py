"""Half peak-to-peak of a periodic signal from its trigonometric series.

Both orbit methods report an orbit's amplitudes this way: shooting from the rfft of its
uniform samples (`fourier_half_range`), harmonic balance from its own H harmonics
(`series_half_range` on the coefficients it solved for; its samples' rfft holds the same
numbers and zeros above H, so summing over all of them only repeats the work, 513 terms
instead of 33 at 32 harmonics: most of a continuation step's time)."""

import jax
import jax.numpy as jnp


def series_half_range(wc, ys, newton_steps: int = 4):
    """Half of (max - min) per component of x(theta) = Re sum_k wc_k exp(i k theta).

    `wc` (K, d): the series' complex weights, k = 0..K-1; `ys` (n, d): the signal at the
    n uniform phases 2 pi j / n, whose best sample starts each extreme. Each extreme is
    polished by Newton's method on x'(theta) = 0 (steps clipped to half a sample), so the
    value is exact to the series, and its derivative with respect to parameters is that of
    x at the extreme (x' = 0 there): a phase change does not leak into the amplitude's
    gradient."""
    n = ys.shape[0]
    k = jnp.arange(wc.shape[0], dtype=float)[:, None]

    def series(theta, order):  # theta (2, d): the maxima's and the minima's phases
        e = jnp.exp(1j * k[None] * theta[:, None, :])
        return jnp.real(jnp.sum(wc[None] * (1j * k[None]) ** order * e, axis=1))

    sign = jnp.array([1.0, -1.0])[:, None]
    # The first best sample of each extreme (jnp.argmax's choice; as a max and a masked
    # min, a third of argmax's time on XLA's CPU: its reduction carries index pairs).
    idx = jnp.arange(n)[None, :, None]
    best = jnp.stack([jnp.max(ys, axis=0), jnp.min(ys, axis=0)])
    first = jnp.min(jnp.where(ys[None] == best[:, None, :], idx, n), axis=1)
    theta = 2.0 * jnp.pi * first / n

    def polish(_, theta):  # one Newton step on x'(theta) = 0 for both extremes
        d1, d2 = series(theta, 1), series(theta, 2)
        ok = sign * d2 < 0.0
        step = jnp.where(ok, d1 / jnp.where(ok, d2, 1.0), 0.0)
        return theta - jnp.clip(step, -jnp.pi / n, jnp.pi / n)

    # A loop, not Python-unrolled: the program holds the series once.
    theta = jax.lax.fori_loop(0, newton_steps, polish, theta)
    extremes = series(theta, 0)
    return 0.5 * (extremes[0] - extremes[1])


def fourier_half_range(ys, newton_steps: int = 4):
    """Half of (max - min) per component of uniform samples `ys` (K, d) over one period,
    by their trigonometric interpolant (`series_half_range` on its rfft)."""
    n = ys.shape[0]
    c = jnp.fft.rfft(ys, axis=0) / n  # (n // 2 + 1, d)
    k = jnp.arange(c.shape[0])[:, None]
    weight = jnp.where((k == 0) | (2 * k == n), 1.0, 2.0)
    return series_half_range(weight * c, ys, newton_steps)
