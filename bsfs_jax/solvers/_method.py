"""The orbit-method interface: what `periodic_orbit`, `continue_orbits` and the
continuation kernel ask of a discretisation of a periodic orbit.

`Shooting` (`_shooting.py`) and `HarmonicBalance` (`_harmonic.py`) are its two final
implementations. As in equinox and diffrax (`AbstractSolver`), the base is abstract and
holds no concrete method, so the engine never switches on the type of its method: each
question that differs between them (truncation error, harmonic refinement, how the method
is described) is a method here.
"""

import abc

import equinox as eqx

from ._half_range import fourier_half_range


class AbstractOrbitMethod(eqx.Module):
    """A discretisation of a periodic orbit of period n T: its unknowns z (scaled by
    `scale`), its residual R(z) = 0, and what follows from a solution.

    Class attributes: `name` (for messages and reports), `uses_chord` (whether the
    continuation corrector tries chord iterations with a neighbour's Newton matrix first:
    worth it where a residual costs far less than a Jacobian), `assembled_jacobian`
    (whether `residual_and_jacobian` assembles dR/dz more cheaply than forward mode through
    the residual; then the corrector uses it) and `runs_long` (whether the corrector's
    program is compiled with XLA's newer CPU fusion emitters, which take about twice as
    long to compile and pay only where each call runs long loops: ODE solves).
    """

    name: eqx.AbstractClassVar[str]
    uses_chord: eqx.AbstractClassVar[bool]
    assembled_jacobian: eqx.AbstractClassVar[bool]
    runs_long: eqx.AbstractClassVar[bool]

    @abc.abstractmethod
    def init(self, vector_field, y_guess, args, period, n_periods, scale):
        """Unknowns from a state guess at t = 0 (mod T)."""

    def init_from_samples(self, ys, scale):
        """Unknowns from states `ys` (N, d) at N equally spaced times over [0, n T) (the
        last period of a transient), on the host, without integrating; None where the
        method cannot (then `init` from ys[0])."""
        return None

    @abc.abstractmethod
    def residual(self, vector_field, z, args, period, n_periods, scale, ode_adjoint=None):
        """R(z), zero on the orbit."""

    @abc.abstractmethod
    def residual_and_jacobian(self, vector_field, z, args, period, n_periods, scale):
        """(R(z), dR/dz)."""

    @abc.abstractmethod
    def initial_state(self, z, period, n_periods, scale):
        """The orbit's state at t = 0 (system units)."""

    @abc.abstractmethod
    def monodromy(self, vector_field, z, args, period, n_periods, scale, jacobian):
        """The scaled monodromy matrix at the solution (`jacobian`: Newton's, dR/dz)."""

    @abc.abstractmethod
    def samples(self, vector_field, z, args, period, n_periods, scale, ode_adjoint=None):
        """(ts, ys): the orbit on a uniform grid over [0, n T)."""

    def amplitudes(self, vector_field, z, args, period, n_periods, scale, ode_adjoint=None):
        """Half peak-to-peak of every state component over the orbit (system units): by
        default from the trigonometric interpolant of `samples` (extremes polished by
        Newton's method, `fourier_half_range`)."""
        _, ys = self.samples(vector_field, z, args, period, n_periods, scale, ode_adjoint)
        return fourier_half_range(ys)

    @abc.abstractmethod
    def trajectory(self, vector_field, z, args, period, n_periods, scale, ts,
                   ode_adjoint=None):
        """The orbit's states at the times `ts` in [0, n T]."""

    @abc.abstractmethod
    def error_estimate(self, vector_field, z, args, period, n_periods, scale, residual):
        """The discretisation's error at the solution (relative, scaled)."""

    @abc.abstractmethod
    def flag_truncation(self, result, error):
        """`result` (a `RESULTS` code), or `harmonics_insufficient` where the method's
        truncation error `error` is above its tolerance (traceable)."""

    @abc.abstractmethod
    def accurate_tol(self) -> float | None:
        """The error estimate below which an orbit counts as resolved (None: the method has
        no truncation error of its own)."""

    @abc.abstractmethod
    def refine(self, orbit, solve, state_size: int):
        """With concrete values: raise the resolution while the orbit is unresolved.
        `solve(method, unknowns)` solves again; returns the last orbit."""

    @abc.abstractmethod
    def discretisation(self) -> dict:
        """{"harmonics": H or None, "segments": m or None}, for reports."""
