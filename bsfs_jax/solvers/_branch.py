"""Results of a continuation: host-side points, events and the `Branch`."""

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class HostPoint:
    """One corrected point of a branch (numpy), as the continuation loop keeps it.

    `u` = (scaled unknowns, p / p_scale); `tangent` the unit tangent there; `jacobian` the
    Newton matrix of the augmented system and `lu` the LU factors of the corrector's
    matrix (device arrays, dropped from stored points by `light`); `mu` the Floquet
    multipliers (largest modulus first); `amplitudes` half peak-to-peak per state
    component; `slope` dA/ds of the branch's amplitude coordinate; `error` the method's
    error estimate; `state` the orbit's state at t = 0 in the system's units.
    """

    u: np.ndarray
    tangent: np.ndarray
    jacobian: np.ndarray
    residual: float
    steps: int
    ok: bool
    mu: np.ndarray
    amplitudes: np.ndarray
    slope: float
    error: float
    accurate: bool
    state: np.ndarray
    ds_used: float = 0.0
    lu: tuple | None = None

    def light(self) -> "HostPoint":
        """The point without its matrices (kept only where still needed: memory)."""
        return dataclasses.replace(self, jacobian=None, lu=None)

    @property
    def converged(self) -> bool:
        return bool(self.ok) and bool(np.all(np.isfinite(self.u))) and bool(
            np.all(np.isfinite(self.tangent)))

    def p(self, p_scale: float) -> float:
        return float(self.u[-1] * p_scale)

    def oriented(self, sign: float) -> "HostPoint":
        return dataclasses.replace(self, tangent=self.tangent * sign, slope=self.slope * sign)


def as_host(pt, accurate_tol: float | None, ds_used: float = 0.0) -> HostPoint:
    """`HostPoint` from the jitted corrector's output (the matrices stay on the device)."""
    import jax

    small = jax.device_get((pt.u, pt.tangent, pt.residual, pt.steps, pt.ok, pt.monodromy,
                            pt.amplitudes, pt.slope, pt.error, pt.state))
    u, tangent, residual, steps, ok, mono, amplitudes, slope, error, state = small
    mu = np.linalg.eigvals(mono) if np.all(np.isfinite(mono)) else np.full(
        mono.shape[0], np.nan + 0j)
    mu = mu[np.argsort(-np.abs(mu), kind="stable")]
    err = float(error)
    accurate = True if accurate_tol is None else bool(err <= accurate_tol)
    return HostPoint(np.array(u), np.array(tangent), pt.jacobian, float(residual), int(steps),
                     bool(ok), mu, np.asarray(amplitudes), float(slope), err, accurate,
                     np.asarray(state), ds_used, (pt.lu, pt.pivots))


def test_values(pt: HostPoint) -> np.ndarray:
    """(dp/ds, prod(mu - 1), prod(mu + 1), prod_{i<j}(mu_i mu_j - 1), dA/ds)."""
    mu = pt.mu
    pairs = [mu[i] * mu[j] - 1.0 for i in range(len(mu)) for j in range(i + 1, len(mu))]
    return np.array([float(pt.tangent[-1]), np.prod(mu - 1.0).real, np.prod(mu + 1.0).real,
                     np.prod(pairs).real if pairs else 1.0, pt.slope])


@dataclasses.dataclass(frozen=True)
class Bifurcation:
    """A located bifurcation point of a branch.

    - `kind`: "fold", "branch-point", "period-doubling" or "neimark-sacker";
    - `p`: parameter value; `state`: orbit state at t = 0; `amplitude`: half peak-to-peak
      of the branch's amplitude coordinate; `amplitudes`: of every coordinate;
    - `multipliers`: Floquet multipliers there (largest modulus first);
    - `index`: the branch point just before the event; `located`: whether the location
      converged (else `p` is the best bracket estimate);
    - `point`: the corrected `HostPoint` there (unknowns, tangent, Newton matrix: what the
      implicit derivative of a fold's parameter value needs).
    """

    kind: str
    p: float
    state: np.ndarray
    amplitude: float
    amplitudes: np.ndarray
    multipliers: np.ndarray
    index: int
    located: bool
    point: HostPoint | None = dataclasses.field(default=None, repr=False, compare=False)

    def as_dict(self):
        return {"type": self.kind, "p": self.p, "amplitude": self.amplitude,
                "multipliers_real": self.multipliers.real.tolist(),
                "multipliers_imag": self.multipliers.imag.tolist(),
                "multiplier_moduli": np.abs(self.multipliers).tolist(),
                "state": self.state.tolist(), "branch_index": self.index,
                "located": self.located}


@dataclasses.dataclass(frozen=True)
class Peak:
    """A local maximum of the branch's amplitude along the arclength (dA/ds = 0).

    `p`, `amplitude` (of the amplitude coordinate), `amplitudes`, `state`; `point` the
    corrected `HostPoint` there (unknowns, tangent, Newton matrix: what the implicit
    derivative of the peak needs); `index` the branch point before it; `located` whether
    |dA/ds| was driven to round-off; `slope` the remaining dA/ds.
    """

    p: float
    amplitude: float
    amplitudes: np.ndarray
    state: np.ndarray
    point: HostPoint
    index: int
    located: bool
    slope: float


@dataclasses.dataclass(frozen=True)
class Branch:
    """A continued branch of periodic orbits (numpy arrays, one row per point).

    - `p` (n,): parameter values; `states` (n, N): orbit states at t = 0 (mod T);
    - `amplitudes` (n, N): half peak-to-peak of every coordinate; `amplitude` (n,): that of
      coordinate `amplitude_index`;
    - `multipliers` (n, N) complex, largest modulus first; `stable` (n,) bool;
    - `arclength` (n,); `residuals` (n,): Newton residuals; `error_estimates` (n,): the
      method's error estimate per point (harmonic balance: the time-domain defect);
      `newton_steps` (n,);
    - `bifurcations`: located `Bifurcation`s; `peaks`: located amplitude maxima (`Peak`);
    - `n_periods`; `info`: run statistics (method, steps, rejections, why it stopped);
    - `method`: the orbit method used at the end (e.g. the final harmonic count);
      `scale`: the state scale of the unknowns.
    """

    p: np.ndarray
    states: np.ndarray
    amplitudes: np.ndarray
    amplitude_index: int
    multipliers: np.ndarray
    stable: np.ndarray
    arclength: np.ndarray
    residuals: np.ndarray
    error_estimates: np.ndarray
    newton_steps: np.ndarray
    bifurcations: tuple
    peaks: tuple
    n_periods: int
    info: dict
    method: object = None
    scale: np.ndarray | None = None

    @property
    def amplitude(self):
        return self.amplitudes[:, self.amplitude_index]

    @property
    def peak(self) -> Peak | None:
        """The largest located amplitude maximum inside the branch, or None when the
        amplitude has no interior maximum (it is largest at an end of the interval) or
        when the continuation did not look for one (`info["peaks_searched"]` False)."""
        if not self.peaks:
            return None
        return max(self.peaks, key=lambda pk: pk.amplitude)

    def __len__(self):
        return int(self.p.shape[0])
