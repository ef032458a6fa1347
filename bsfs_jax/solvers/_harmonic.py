"""Harmonic balance with the alternating frequency-time (AFT) scheme.

The orbit of period n T of the first-order system y' = f(t, y, args) is written in scaled
variables z = y / scale as a truncated Fourier series in Omega = 2 pi / (n T):

    z(t) = c_0 + sum_{k=1..H} a_k cos(k Omega t) + b_k sin(k Omega t).

The unknowns are (c_0, a_1..a_H, b_1..b_H), d (2H + 1) numbers for d states. The AFT
residual samples z at N equally spaced times (inverse real FFT), evaluates the vector field
there, takes the harmonics of the result (real FFT) and balances them against those of z':

    r_0 = -g_0 / Omega,   r_a,k = k b_k - g_a,k / Omega,   r_b,k = -k a_k - g_b,k / Omega,

a Galerkin projection on the first H harmonics (N = 4H samples keep aliasing of the
nonlinear terms small). Dividing by Omega makes the residual dimensionless, of the order
of the unknowns.

**Jacobian.** Newton's dR/dz is assembled from the field's Jacobian at the N samples:
its DFT, convolved with the harmonics (`residual_and_jacobian`), the exact derivative of the
AFT residual (aliasing included) at the cost of d forward passes of the field per sample
and d^2 FFTs, where forward mode through the residual took one pass of everything per
unknown, d (2H + 1) of them (at H = 32 on the ball screw: 0.7 ms against 1.7 ms).

**Error estimate.** HB zeroes the first H harmonics of the defect z' - g(t, z) but not the
rest. `error_estimate` evaluates the reconstructed orbit and its derivative on a grid
eight times finer than the AFT grid (the time-domain residual of the reconstruction) and
integrates it once over time: the state error that the missing forcing drives (see the
method). `periodic_orbit` doubles H until it is below `error_tol`.

**Stability.** The Floquet multipliers of an HB orbit are those of the monodromy matrix of
the variational equation w' = A(t) w, A = df/dz along the reconstructed orbit: one period
map of the linearisation at the HB state, integrated by the classical fourth-order
Runge-Kutta method on 256 fixed steps per period, with A taken from the Fourier series on
the uniform half-step grid (one inverse FFT). No adaptive ODE solve, a fixed cost of about
a millisecond, and multipliers whose error (tested against shooting) is far below what
stability and bifurcation detection need. Hill's method (the eigenvalues of the HB
Jacobian) was not used: it returns d (2H + 1) exponents of which d must be picked by a
sorting heuristic that fails near bifurcations, where the answer matters most.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._numerics import solve_small
from . import _harmonic_second as second
from ._aft_layout import aft_jacobian_layout, chained_layout, derivative_blocks
from ._half_range import series_half_range
from ._method import AbstractOrbitMethod
from ._results import RESULTS
from ._shooting import SHOOTING_SETTINGS, Scaled, flow

_MAGNUS_STEPS = 256  # Runge-Kutta steps per orbit period for the monodromy


class HarmonicBalance(AbstractOrbitMethod):
    """Harmonic balance with `harmonics` harmonics of the orbit frequency (AFT, `time_samples`
    time points per orbit period; default 4 * harmonics, at least 16).

    Pass as `method=` to `periodic_orbit` (which raises the harmonic count until the error
    estimate meets `tol`, up to `max_harmonics`) or to `continue_orbits`.

    `second_order=True`: for a state (x, v) with x' = v exactly (a mechanical system,
    positions then velocities), the unknowns are the positions' coefficients alone
    (`_harmonic_second.py`): the same orbits with half the unknowns.
    """

    harmonics: int = eqx.field(static=True, default=16)
    time_samples: int | None = eqx.field(static=True, default=None)
    max_harmonics: int = eqx.field(static=True, default=128)
    error_tol: float = eqx.field(static=True, default=1e-4)
    second_order: bool = eqx.field(static=True, default=False)

    name = "harmonic balance"
    uses_chord = True  # a residual costs far less than a Jacobian + LU: chord first
    assembled_jacobian = True  # from the AFT of the field's Jacobian
    runs_long = False  # FFTs and an LU: the earlier fusion emitters (compile in half)

    def __check_init__(self):
        if int(self.harmonics) < 1:
            raise ValueError(f"HarmonicBalance needs harmonics >= 1, got {self.harmonics}")
        if self.time_samples is not None and int(self.time_samples) < 2 * self.harmonics + 1:
            raise ValueError(f"HarmonicBalance needs samples >= 2 harmonics + 1 = "
                             f"{2 * self.harmonics + 1}, got {self.time_samples}")

    @property
    def n_samples(self) -> int:
        return (int(self.time_samples) if self.time_samples is not None
                else max(16, 4 * self.harmonics))

    def with_harmonics(self, h: int) -> "HarmonicBalance":
        return HarmonicBalance(int(h), None, self.max_harmonics, self.error_tol,
                               self.second_order)

    def width(self, d: int) -> int:
        """Unknowns per harmonic coefficient for a state of size d (d / 2 where
        `second_order`: the positions only)."""
        if not self.second_order:
            return int(d)
        if int(d) % 2:
            raise ValueError(f"HarmonicBalance(second_order=True) needs a state (x, v) of "
                             f"even size, got {d}")
        return int(d) // 2

    def size(self, d: int) -> int:
        """Number of unknowns for a state of size d."""
        return self.width(d) * (2 * int(self.harmonics) + 1)

    def _first(self) -> "HarmonicBalance":
        """The first-order method of the same resolution (what `second_order` expands to)."""
        return HarmonicBalance(self.harmonics, self.time_samples, self.max_harmonics,
                               self.error_tol) if self.second_order else self

    def _full(self, z, period, n_periods, scale):
        """First-order coefficients of the unknowns."""
        if not self.second_order:
            return z
        return second.expand(z, int(self.harmonics), scale.shape[0],
                             2.0 * jnp.pi / (n_periods * period), scale)

    # -- what the engine asks of every method (`AbstractOrbitMethod`) ----------------------
    def flag_truncation(self, result, error):
        return RESULTS.where((result == RESULTS.successful) & ~(error <= self.error_tol),
                             RESULTS.harmonics_insufficient, result)

    def accurate_tol(self) -> float | None:
        return self.error_tol

    def refine(self, orbit, solve, state_size: int):
        """Double the harmonic count while the error estimate is above `error_tol`, up to
        `max_harmonics`, each time from the last orbit's coefficients."""
        while (not bool(orbit.converged)) and orbit.result == RESULTS.harmonics_insufficient \
                and 2 * orbit.method.harmonics <= self.max_harmonics:
            bigger = orbit.method.with_harmonics(2 * orbit.method.harmonics)
            orbit = solve(bigger, bigger.from_coefficients(orbit.method, orbit.unknowns,
                                                             state_size))
        return orbit

    def discretisation(self) -> dict:
        return {"harmonics": int(self.harmonics), "segments": None,
                **({"second_order": True} if self.second_order else {})}

    # -- coefficients <-> time samples ---------------------------------------------------
    def _unpack(self, z, d):
        h = self.harmonics
        c0 = z[:d]
        a = z[d:d + h * d].reshape(h, d)
        b = z[d + h * d:].reshape(h, d)
        return c0, a, b

    def _spectrum(self, z, d, n):
        """rfft-layout spectrum (n // 2 + 1, d) of the series for an n-point grid."""
        c0, a, b = self._unpack(z, d)
        spec = jnp.zeros((n // 2 + 1, d), dtype=complex)
        spec = spec.at[0].set(n * c0)
        return spec.at[1:self.harmonics + 1].set(0.5 * n * (a - 1j * b))

    def _to_time(self, z, d, n, derivative: int = 0):
        """z (or its derivative of that order w.r.t. Omega t) at t_j = j nT / n."""
        spec = self._spectrum(z, d, n)
        if derivative:
            k = jnp.arange(n // 2 + 1)[:, None]
            spec = spec * (1j * k) ** derivative
        return jnp.fft.irfft(spec, n=n, axis=0)

    def _to_coeffs(self, g):
        n, d = g.shape
        spec = jnp.fft.rfft(g, axis=0)
        h = self.harmonics
        c0 = spec[0].real / n
        a = 2.0 * spec[1:h + 1].real / n
        b = -2.0 * spec[1:h + 1].imag / n
        return jnp.concatenate([c0, a.reshape(-1), b.reshape(-1)])

    # -- the method interface --------------------------------------------------------------
    def init(self, vector_field, y_guess, args, period, n_periods, scale):
        """Coefficients of one orbit period integrated from the guess (a good start when
        the guess lies near the orbit, e.g. the end of a transient)."""
        n = self.n_samples
        t_end = n_periods * period
        ts = t_end * jnp.arange(n) / n
        zs = flow(vector_field, y_guess / scale, args, scale, jnp.zeros_like(t_end), t_end,
                  ts, SHOOTING_SETTINGS)
        zs = jnp.where(jnp.isfinite(zs), zs, 0.0)
        z = self._to_coeffs(zs)
        return second.positions(z, int(self.harmonics), zs.shape[1]) if self.second_order \
            else z

    def init_from_samples(self, ys, scale):
        """The samples' Fourier coefficients (numpy: no program), harmonics beyond the
        grid's Nyquist limit zero: the same start as `init` where ys is one period of the
        flow from the guess, without integrating it."""
        ys, scale = np.asarray(ys, dtype=float), np.asarray(scale, dtype=float)
        n, d = ys.shape
        if n < 4:  # not a period's worth: integrate one from the first state (`init`)
            return None
        h = int(self.harmonics)
        k = min(h, (n - 1) // 2)
        spec = np.fft.rfft(ys / scale, axis=0)
        a, b = np.zeros((h, d)), np.zeros((h, d))
        a[:k], b[:k] = 2.0 * spec[1:k + 1].real / n, -2.0 * spec[1:k + 1].imag / n
        z = np.concatenate([spec[0].real / n, a.reshape(-1), b.reshape(-1)])
        if not self.second_order:
            return z
        self.width(d)  # refuses an odd state size
        return second.positions(z, h, d)

    def from_coefficients(self, other: "HarmonicBalance", z, d, xp=jnp):
        """Unknowns of this method from another HB's unknowns (padding or truncating).
        `xp=numpy` for host-side arrays (no op-by-op programs)."""
        if bool(other.second_order) != bool(self.second_order):
            raise ValueError("from_coefficients: both methods must be first order or both "
                             "second order")
        d = self.width(d)
        c0, a, b = other._unpack(z, d)
        h = self.harmonics
        pad = max(0, h - other.harmonics)
        a = xp.concatenate([a, xp.zeros((pad, d))])[:h]
        b = xp.concatenate([b, xp.zeros((pad, d))])[:h]
        return xp.concatenate([c0, a.reshape(-1), b.reshape(-1)])

    def residual(self, vector_field, z, args, period, n_periods, scale, ode_adjoint=None):
        if self.second_order:
            r = self._first().residual(vector_field, self._full(z, period, n_periods, scale),
                                       args, period, n_periods, scale)
            return second.velocity_rows(r, int(self.harmonics), scale.shape[0])
        d = scale.shape[0]
        n = self.n_samples
        t_end = n_periods * period
        omega = 2.0 * jnp.pi / t_end
        ts = t_end * jnp.arange(n) / n
        zs = self._to_time(z, d, n)
        g = jax.vmap(lambda t, zz: Scaled(vector_field)(t, zz, (args, scale)))(ts, zs)
        return self._balance(z, g, omega, d)

    def _balance(self, z, g, omega, d):
        """The residual from the field's samples g (N, d) on the AFT grid."""
        c0, a, b = self._unpack(z, d)
        k = jnp.arange(1, self.harmonics + 1)[:, None]
        g0, ga, gb = self._unpack(self._to_coeffs(g) / omega, d)
        return jnp.concatenate([-g0, (k * b - ga).reshape(-1), (-k * a - gb).reshape(-1)])

    def residual_and_jacobian(self, vector_field, z, args, period, n_periods, scale):
        """(R(z), dR/dz) with the Jacobian assembled from the AFT of the field's Jacobian.

        With A_j = dg/dz at the N samples and Ahat_m their DFT / N (d x d each), the
        coefficients P_k of A(t) y(t) on the AFT grid are the cyclic convolution
        sum_l Ahat_(k - l mod N) Y_l of the complex harmonics Y_l (Y_0 = c_0,
        Y_(+-l) = (a_l -+ i b_l) / 2), exactly as the residual's FFTs compute them. So
        dP_k/dc_0 = Ahat_k, dP_k/da_l = (Ahat_(k-l) + Ahat_(k+l)) / 2 and
        dP_k/db_l = i (Ahat_(k+l) - Ahat_(k-l)) / 2, and the real rows are Re P_0,
        2 Re P_k, -2 Im P_k. One Jacobian of the field per sample and d^2 FFTs, instead of
        one forward-mode pass of the whole residual per unknown (d (2H + 1) of them):
        equal to `jax.jacfwd` of `residual` to rounding (tested). With `second_order`, the
        velocity rows, chained through the positions-to-velocities map."""
        d = scale.shape[0]
        n = self.n_samples
        h = self.harmonics
        t_end = n_periods * period
        omega = 2.0 * jnp.pi / t_end
        ts = t_end * jnp.arange(n) / n
        z = self._full(z, period, n_periods, scale)
        zs = self._to_time(z, d, n)
        field = Scaled(vector_field)

        def value_and_a(t, zz):
            f = lambda v: field(t, v, (args, scale))  # noqa: E731
            return f(zz), jax.jacfwd(f)(zz)

        g, a = jax.vmap(value_and_a)(ts, zs)
        r = self._balance(z, g, omega, d)
        w1, w2, c1, c2 = aft_jacobian_layout(h, n)
        if self.second_order:
            # Only the velocity rows (the position rows are the identity x' = v).
            ahat = jnp.fft.fft(a[:, d // 2:], axis=0) / n
            table = jnp.concatenate([ahat.real, ahat.imag])
            return (second.velocity_rows(r, h, d),
                    second.assemble(table, (w1, w2, c1, c2), chained_layout(h, n), h, d,
                                    omega, scale))
        # Ahat_m = alpha_m + i beta_m, m = 0..N-1 (negative m wrap around), (N, d, d).
        ahat = jnp.fft.fft(a, axis=0) / n
        table = jnp.concatenate([ahat.real, ahat.imag])  # alpha at m, beta at N + m
        blocks = c1[..., None, None] * table[w1] + c2[..., None, None] * table[w2]
        m = jnp.transpose(blocks, (0, 2, 1, 3)).reshape((2 * h + 1) * d, (2 * h + 1) * d)
        # dR/dz = D - M / omega, D: +k on (a_k rows, b_k cols), -k on (b_k rows, a_k cols).
        dmat = jnp.kron(derivative_blocks(h), jnp.eye(d))
        return r, dmat - m / omega

    def chord(self, vector_field, z, args, period, n_periods, scale, jacobian, steps: int):
        """`steps` chord iterations z <- z - J^-1 R(z) of this method's residual from z,
        stacked (steps, len(z)).

        J is the residual's Jacobian for the linear field z' = `jacobian` z (scaled
        states: `jacobian` is d(f(t, z * scale) / scale)/dz at the expansion point). It is
        block-diagonal: -jacobian / omega on the mean and, on harmonic k, i k - jacobian /
        omega acting on a_k - i b_k, so each step costs one residual and H + 1 solves of
        size d. From z = 0, with the field's nonlinear part zero there, the first iterate
        is the linear steady state and the next ones are successive corrections for the
        nonlinearity (first order, second order, ...). Traceable and differentiable.
        """
        d = scale.shape[0]
        omega = 2.0 * jnp.pi / (n_periods * period)
        if self.second_order:
            b0, blocks = second.chord_blocks(jacobian, int(self.harmonics), d, omega, scale)
            d = self.width(d)
        else:
            b0 = -jnp.asarray(jacobian) / omega
            k = jnp.arange(1, self.harmonics + 1)
            blocks = 1j * k[:, None, None] * jnp.eye(d)[None] + b0[None].astype(complex)

        def step(zz, _):
            r0, ra, rb = self._unpack(self.residual(vector_field, zz, args, period,
                                                    n_periods, scale), d)
            # Plain-array solves, not LAPACK: this runs vmapped over thousands of FRF
            # lines, where two batched LAPACK calls deadlock jaxlib's CPU thread pool
            # (`solve_small`).
            dz = solve_small(blocks, (ra - 1j * rb)[..., None])[..., 0]
            d0 = solve_small(b0, r0[..., None])[..., 0]
            new = zz - jnp.concatenate([d0, dz.real.reshape(-1), (-dz.imag).reshape(-1)])
            return new, new

        return jax.lax.scan(step, z, None, length=int(steps))[1]

    def initial_state(self, z, period, n_periods, scale):
        d = scale.shape[0]
        c0, a, _ = self._unpack(self._full(z, period, n_periods, scale), d)
        return (c0 + jnp.sum(a, axis=0)) * scale

    def samples(self, vector_field, z, args, period, n_periods, scale, ode_adjoint=None):
        """(ts, ys) on a grid of 8 N points over [0, n T), from the series."""
        z = self._full(z, period, n_periods, scale)
        d = scale.shape[0]
        n = 8 * self.n_samples
        ts = n_periods * period * jnp.arange(n) / n
        return ts, self._to_time(z, d, n) * scale[None, :]

    def amplitudes(self, vector_field, z, args, period, n_periods, scale, ode_adjoint=None):
        """Half peak-to-peak of every component, from the H harmonics themselves
        (`series_half_range`), each extreme started at the best of the `samples` grid's
        points: the samples' interpolant is the same series (its harmonics above H are
        zero), so this is the default's value in about a ninth of the time (its jvp at 32
        harmonics on the ball screw 0.33 ms against 2.94 ms)."""
        _, ys = self.samples(vector_field, z, args, period, n_periods, scale)
        z = self._full(z, period, n_periods, scale)
        d = scale.shape[0]
        c0, a, b = self._unpack(z, d)
        wc = jnp.concatenate([c0[None].astype(complex), a - 1j * b]) * scale[None, :]
        return series_half_range(wc, ys)

    def trajectory(self, vector_field, z, args, period, n_periods, scale, ts,
                   ode_adjoint=None):
        """States at times `ts` from the Fourier series."""
        z = self._full(z, period, n_periods, scale)
        d = scale.shape[0]
        c0, a, b = self._unpack(z, d)
        omega = 2.0 * jnp.pi / (n_periods * period)
        k = jnp.arange(1, self.harmonics + 1)
        arg = omega * jnp.asarray(ts)[:, None] * k[None, :]
        zs = c0[None, :] + jnp.cos(arg) @ a + jnp.sin(arg) @ b
        return zs * scale[None, :]

    def error_estimate(self, vector_field, z, args, period, n_periods, scale, residual=None):
        """Estimated truncation error of the orbit, relative to max(1, max|z|).

        The defect e(t) = z' - g(t, z) of the reconstruction on a grid 8x finer than the
        AFT grid is the forcing that the truncated series misses. Its first H harmonics,
        less the AFT residual (Newton's own, reported separately), are the aliasing error;
        the harmonics above H are the truncation. Their time integral (the zero-mean
        antiderivative, harmonic k divided by i k Omega) is the state error they drive at
        the high frequencies where they live (there the response is inertia dominated, a
        pure integration). The max over time and states is returned.
        """
        if self.second_order:
            return self._first().error_estimate(
                vector_field, self._full(z, period, n_periods, scale), args, period,
                n_periods, scale, residual)
        d = scale.shape[0]
        n = 8 * self.n_samples
        t_end = n_periods * period
        omega = 2.0 * jnp.pi / t_end
        ts = t_end * jnp.arange(n) / n
        zs = self._to_time(z, d, n)
        dz = self._to_time(z, d, n, derivative=1)  # dz / d(Omega t)
        g = jax.vmap(lambda t, zz: Scaled(vector_field)(t, zz, (args, scale)))(ts, zs)
        spec = jnp.fft.rfft(dz - g / omega, axis=0)
        # Remove the AFT residual (the coarse grid's defect harmonics, what Newton zeroes).
        spec = spec - self._spectrum(self.residual(vector_field, z, args, period, n_periods,
                                                   scale), d, n)
        k = jnp.arange(spec.shape[0])[:, None]
        integral = jnp.fft.irfft(jnp.where(k > 0, spec / (1j * jnp.maximum(k, 1)), 0.0), n=n,
                                 axis=0)
        size = jnp.maximum(1.0, jnp.max(jnp.abs(zs)))
        return jnp.max(jnp.abs(integral)) / size

    def monodromy(self, vector_field, z, args, period, n_periods, scale, jacobian=None):
        """Scaled monodromy matrix: classical Runge-Kutta (4th order) on the variational
        equation w' = A(t) w, A = dg/dz along the series, 256 steps per orbit period (128
        for 8 harmonics or fewer).
        A is evaluated on the uniform half-step grid from the series by one inverse FFT,
        so the step matrices are three products of 6 x 6 matrices each."""
        z = self._full(z, period, n_periods, scale)
        d = scale.shape[0]
        t_end = n_periods * period
        m = _MAGNUS_STEPS if self.n_samples > 32 else _MAGNUS_STEPS // 2
        h = t_end / m
        ts = t_end * jnp.arange(2 * m + 1) / (2 * m)
        zs = self._to_time(z, d, 2 * m)
        zs = jnp.concatenate([zs, zs[:1]])
        field = Scaled(vector_field)

        def a_of(t, zz):
            return jax.jacfwd(lambda v: field(t, v, (args, scale)))(zz)

        a = jax.vmap(a_of)(ts, zs)
        a0, am, a1 = a[0:-1:2], a[1::2], a[2::2]
        eye = jnp.eye(d)[None]
        k1 = a0
        k2 = am @ (eye + 0.5 * h * k1)
        k3 = am @ (eye + 0.5 * h * k2)
        k4 = a1 @ (eye + h * k3)
        steps = eye + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        # A sequential product (a loop of 6 x 6 products; a parallel prefix product
        # would compile eight levels of slices for no gain at this size).
        return jax.lax.scan(lambda acc, s: (s @ acc, None), jnp.eye(d, dtype=steps.dtype),
                            steps)[0]
