"""Pseudo-arclength continuation of periodic orbits on the engine (shooting and harmonic
balance): Duffing folds against the closed-form one-term harmonic balance and against each
other, a period doubling against a brute-force sweep, the BSFS against `simulate`, the
FRC peak, trimming, and the CLI."""

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsfs_jax.machine import bsfs_family, simulate
from bsfs_jax.params import preset
from bsfs_jax.solvers import (
    HarmonicBalance,
    SolverSettings,
    continue_orbits,
    integrate,
    periodic_orbit,
)

from .textbook import duffing


class DuffingFamily(eqx.Module):
    """Duffing oscillator along a line in its parameters: args(p) = base + p * direction.

    args = (delta, alpha, beta, gamma, omega); the period is 2 pi / omega. One class for
    the frequency and the amplitude continuations, so both share one compiled corrector.
    """

    base: jax.Array
    direction: jax.Array

    def __call__(self, p):
        a = self.base + p * self.direction
        return (a[0], a[1], a[2], a[3], a[4]), 2 * jnp.pi / a[4]


def frequency_family(delta, alpha, beta, gamma):
    return DuffingFamily(jnp.array([delta, alpha, beta, gamma, 0.0]),
                         jnp.array([0.0, 0.0, 0.0, 0.0, 1.0]))


def amplitude_family(delta, alpha, beta, omega):
    return DuffingFamily(jnp.array([delta, alpha, beta, 0.0, omega]),
                         jnp.array([0.0, 0.0, 0.0, 1.0, 0.0]))


def harmonic_balance_curve(delta, alpha, beta, gamma, a_max=10.0, n=400_001):
    """One-term harmonic balance x = A cos(w t - phi) of the Duffing oscillator.

    [(alpha - w^2 + 3/4 beta A^2)^2 + (delta w)^2] A^2 = gamma^2: for each A a quadratic in
    w^2. Returns the closed curve (w, A) ordered along its arclength (lower root for rising
    A, then the upper root back down).
    """
    amp = np.linspace(1e-4, a_max, n)
    k = alpha + 0.75 * beta * amp**2
    b = delta**2 - 2 * k
    c = k**2 - (gamma / amp) ** 2
    disc = b * b - 4 * c
    ok = disc >= 0
    amp, b, root = amp[ok], b[ok], np.sqrt(disc[ok])
    w2_lo, w2_hi = (-b - root) / 2, (-b + root) / 2
    keep = w2_lo > 0  # drop the (unphysical) w^2 <= 0 part of the lower root
    w = np.concatenate([np.sqrt(w2_lo[keep]), np.sqrt(w2_hi[::-1])])
    a = np.concatenate([amp[keep], amp[::-1]])
    return w, a


def turning_points(w, a):
    """(w, A) where w(s) along the curve has a local extremum (the folds)."""
    dw = np.diff(w)
    idx = np.flatnonzero(np.sign(dw[1:]) != np.sign(dw[:-1])) + 1
    return [(w[i], a[i]) for i in idx]


HARDENING = dict(delta=0.05, alpha=1.0, beta=0.05, gamma=0.1)


@pytest.fixture(scope="module")
def duffing_frc():
    family = frequency_family(**HARDENING)
    return continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                           vector_field=duffing, scale=jnp.ones(2), normalise=False,
                           p_scale=1.0, amplitude_index=0)


@pytest.fixture(scope="module")
def duffing_frc_hb():
    family = frequency_family(**HARDENING)
    return continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                           vector_field=duffing, scale=jnp.ones(2), normalise=False,
                           p_scale=1.0, amplitude_index=0,
                           method=HarmonicBalance(harmonics=4, error_tol=1e-9))


def test_harmonic_balance_folds_match_shooting_folds(duffing_frc, duffing_frc_hb):
    hb, sh = duffing_frc_hb, duffing_frc
    assert hb.info["method"] == "harmonic balance" and sh.info["method"] == "shooting"
    # The error estimate chose the harmonic count (doubling from 4) and holds everywhere.
    assert np.all(hb.error_estimates <= 1e-9) and hb.method.harmonics >= 8
    folds_hb = sorted(b.p for b in hb.bifurcations if b.kind == "fold")
    folds_sh = sorted(b.p for b in sh.bifurcations if b.kind == "fold")
    assert len(folds_hb) == len(folds_sh) == 2
    np.testing.assert_allclose(folds_hb, folds_sh, rtol=1e-7)
    # The same peak, located along the branch (dA/ds = 0) by both methods.
    assert hb.peak.amplitude == pytest.approx(sh.peak.amplitude, rel=1e-7)
    assert hb.peak.located and sh.peak.located


def test_harmonic_count_falls_again_past_the_peak(duffing_frc):
    """From 2 harmonics at tolerance 1e-6 the count rises towards the peak and, past it,
    where half as many meet the estimate again, falls (the rest of the branch is cheaper);
    every point still meets the tolerance, the events are located with the largest count
    and agree with shooting."""
    hb = continue_orbits(frequency_family(**HARDENING), jnp.array([0.1, 0.0]), 0.8, 1.3,
                         ds=0.05, vector_field=duffing, scale=jnp.ones(2), normalise=False,
                         p_scale=1.0, amplitude_index=0,
                         method=HarmonicBalance(harmonics=2, error_tol=1e-6))
    assert hb.info["harmonic_upgrades"] >= 1 and hb.info["harmonic_downgrades"] >= 1
    assert hb.info["stop_reason"] == "left the parameter interval"
    assert np.all(hb.error_estimates <= 1e-6)
    assert hb.method.harmonics == 8  # the branch reports the largest count used
    folds_hb = sorted(b.p for b in hb.bifurcations if b.kind == "fold")
    folds_sh = sorted(b.p for b in duffing_frc.bifurcations if b.kind == "fold")
    np.testing.assert_allclose(folds_hb, folds_sh, rtol=1e-6)
    assert hb.peak.amplitude == pytest.approx(duffing_frc.peak.amplitude, rel=1e-6)
    # Past the peak, on fewer harmonics, each orbit is shooting's orbit at its frequency.
    family = frequency_family(**HARDENING)
    for i in np.flatnonzero(hb.p > 1.2):
        args, period = family(hb.p[i])
        orbit = periodic_orbit(duffing, hb.states[i], args, period, scale=jnp.ones(2))
        np.testing.assert_allclose(hb.states[i], orbit.state, rtol=0, atol=1e-5)


def test_second_order_harmonic_balance_continues_the_same_branch(duffing_frc,
                                                                 duffing_frc_hb):
    """Harmonic balance in the positions alone (`second_order`: half the unknowns) follows
    the first-order method's branch: the same folds and peak to 1e-9, through harmonic
    upgrades and, from 2 harmonics, downgrades past the peak (the unknowns converted
    between counts at half the width)."""
    family = frequency_family(**HARDENING)

    def run(h, tol):
        return continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                               vector_field=duffing, scale=jnp.ones(2), normalise=False,
                               p_scale=1.0, amplitude_index=0,
                               method=HarmonicBalance(harmonics=h, error_tol=tol,
                                                      second_order=True))

    two = run(4, 1e-9)
    assert two.info["second_order"] and two.info["stop_reason"] == "left the parameter " \
        "interval"
    assert np.all(two.error_estimates <= 1e-9)
    assert two.method.harmonics == duffing_frc_hb.method.harmonics
    folds = sorted(b.p for b in two.bifurcations if b.kind == "fold")
    folds_first = sorted(b.p for b in duffing_frc_hb.bifurcations if b.kind == "fold")
    folds_sh = sorted(b.p for b in duffing_frc.bifurcations if b.kind == "fold")
    assert len(folds) == 2
    np.testing.assert_allclose(folds, folds_first, rtol=1e-9)
    np.testing.assert_allclose(folds, folds_sh, rtol=1e-7)
    assert two.peak.amplitude == pytest.approx(duffing_frc_hb.peak.amplitude, rel=1e-9)
    # Every point's state (velocities from the positions' series) is the orbit's.
    for i in range(0, len(two), 7):
        args, period = family(two.p[i])
        orbit = periodic_orbit(duffing, two.states[i], args, period, scale=jnp.ones(2))
        np.testing.assert_allclose(two.states[i], orbit.state, rtol=0, atol=1e-7)
    low = run(2, 1e-6)
    assert low.info["harmonic_upgrades"] >= 1 and low.info["harmonic_downgrades"] >= 1
    assert np.all(low.error_estimates <= 1e-6)
    np.testing.assert_allclose(sorted(b.p for b in low.bifurcations if b.kind == "fold"),
                               folds_sh, rtol=1e-6)


def test_duffing_folds_match_harmonic_balance(duffing_frc):
    branch = duffing_frc
    w_hb, a_hb = harmonic_balance_curve(**HARDENING)
    hb_folds = sorted(turning_points(w_hb, a_hb))
    assert len(hb_folds) == 2  # the HB curve itself has two folds here
    folds = sorted((b for b in branch.bifurcations if b.kind == "fold"), key=lambda b: b.p)
    assert len(folds) == 2, [b.kind for b in branch.bifurcations]
    assert branch.info["stop_reason"] == "left the parameter interval"
    # Trimmed: the branch ends on the interval's bound, not past it.
    assert branch.p[-1] == pytest.approx(1.3, abs=1e-12) and branch.p[0] == pytest.approx(0.8)
    for fold, (w_fold, a_fold) in zip(folds, hb_folds):
        assert fold.located
        # 1-term HB neglects the 3rd harmonic, of relative size ~ beta A^2 / (32 w^2)
        # ~ 0.6 % here; the fold frequencies agree to 0.1 %, amplitudes to 2 %.
        assert fold.p == pytest.approx(w_fold, rel=1e-3)
        assert fold.amplitude == pytest.approx(a_fold, rel=2e-2)
        # At a fold one Floquet multiplier is +1.
        assert np.min(np.abs(fold.multipliers - 1.0)) < 1e-4
    # Peak amplitude within 1.5 % of one-term HB's; the located peak is the branch's
    # largest amplitude, with dA/ds driven to zero between two branch points.
    assert branch.peak.amplitude == pytest.approx(np.max(a_hb), rel=1.5e-2)
    assert branch.peak.amplitude >= np.max(branch.amplitude) - 1e-12
    assert branch.peak.located and abs(branch.peak.slope) < 1e-6


def test_duffing_middle_branch_is_unstable(duffing_frc):
    branch = duffing_frc
    folds = [b for b in branch.bifurcations if b.kind == "fold"]
    first, second = sorted(b.index for b in folds)
    # Between the two folds (along the arclength) the orbits are saddles: a real
    # multiplier > 1; outside, all multipliers lie inside the unit circle.
    middle = np.arange(first + 1, second + 1)
    outside = np.r_[np.arange(0, first + 1), np.arange(second + 1, len(branch))]
    mu_max = np.max(np.abs(branch.multipliers), axis=1)
    assert np.all(mu_max[middle] > 1.0) and not np.any(branch.stable[middle])
    assert np.all(branch.stable[outside])
    real_max = branch.multipliers[middle, 0]
    assert np.all(np.abs(real_max.imag) < 1e-12) and np.all(real_max.real > 1.0)
    # The parameter turns back along the middle branch (it is traversed with w decreasing).
    assert branch.p[second] < branch.p[first]


def test_continuation_does_not_retrace(duffing_frc):
    assert duffing_frc.info["corrector_traces"] <= 1
    # Same family structure, new values: the jitted corrector is reused, not retraced.
    other = frequency_family(delta=0.06, alpha=1.0, beta=0.04, gamma=0.08)
    branch = continue_orbits(other, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                             vector_field=duffing, scale=jnp.ones(2), normalise=False,
                             p_scale=1.0, max_points=4)
    assert branch.info["corrector_traces"] == 0
    assert len(branch) == 4 and branch.info["stop_reason"] == "max_points"


def test_prefetched_corrector_is_not_traced_again(duffing_frc):
    # `bsfs continue` compiles the cross-check's corrector in the background
    # (`prefetch_corrector`); the continuation then finds it in jit's cache: no trace, and
    # the same branch as without the prefetch (another amplitude coordinate: another
    # program than the fixture's, so nothing is cached before the prefetch).
    from bsfs_jax.solvers import Shooting, prefetch_corrector

    family = frequency_family(**HARDENING)
    method = Shooting()  # no harmonic count to raise: one program along the branch
    prefetch_corrector(family, duffing, method, jnp.array([0.1, 0.0]), 0.8,
                       amplitude_index=1).result(timeout=300)
    branch = continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                             vector_field=duffing, scale=jnp.ones(2), normalise=False,
                             p_scale=1.0, amplitude_index=1, method=method, max_points=30)
    assert branch.info["corrector_traces"] == 0
    np.testing.assert_allclose(branch.p, duffing_frc.p[:30], rtol=1e-12)


def test_duffing_period_doubling_matches_brute_force():
    """Double-well Duffing x'' + 0.3 x' - x + x^3 = gamma cos(1.2 t): the period-1 orbit
    in one well period-doubles as gamma grows (the classic route to chaos)."""
    omega = 1.2
    period = 2 * np.pi / omega
    family = amplitude_family(delta=0.3, alpha=-1.0, beta=1.0, omega=omega)
    # Brute force: long simulations from x = 1 (the right well) on a grid of gamma; period
    # 2 shows as x(kT) != x((k+1)T). The first run (gamma = 0.2) gives the start guess.
    gammas = np.r_[0.2, np.round(np.arange(0.250, 0.2801, 0.0025), 6)]
    n_transient, n_keep = 600, 4
    ts = period * jnp.arange(n_transient, n_transient + n_keep + 1)
    settings = SolverSettings(rtol=1e-9, atol=1e-11)

    def strobe(gamma):
        args = (0.3, -1.0, 1.0, gamma, omega)
        return integrate(duffing, jnp.array([1.0, 0.0]), args, 0.0, ts[-1], ts, settings).ys

    ys = np.asarray(jax.jit(jax.vmap(strobe))(jnp.asarray(gammas)))
    guess = ys[0, -1]
    gammas, xs = gammas[1:], ys[1:, :, 0]
    branch = continue_orbits(family, guess, 0.2, 0.32, ds=0.05, vector_field=duffing,
                             scale=jnp.ones(2), normalise=False)
    pds = [b for b in branch.bifurcations if b.kind == "period-doubling"]
    assert len(pds) == 1, [(b.kind, b.p) for b in branch.bifurcations]
    pd = pds[0]
    assert pd.located and np.min(np.abs(pd.multipliers + 1.0)) < 1e-4
    assert np.all(branch.stable[branch.p < pd.p - 1e-3])
    assert not np.any(branch.stable[branch.p > pd.p + 1e-3])

    split = np.max(np.abs(np.diff(xs, axis=1)), axis=1)
    period2 = split > 1e-3
    assert not period2[0] and period2[-1]
    first = int(np.argmax(period2))
    assert np.all(period2[first:])  # one clean transition on the grid
    # The continuation's PD lies in the bracket the sweep observes (grid step 0.0025).
    assert gammas[first - 1] < pd.p <= gammas[first]

    # Beyond it, shooting for a 2T-periodic orbit finds the period-2 attractor of the sweep.
    settled = ys[-1, -1]  # gamma = 0.28, after 604 periods
    assert np.max(np.abs(xs[-1, 2:] - xs[-1, :-2])) < 1e-6  # period 2, not 4, at 0.28
    args_28, _ = family(gammas[-1])
    orbit2 = periodic_orbit(duffing, settled + 0.01, args_28, period, n_periods=2,
                            scale=jnp.ones(2))
    np.testing.assert_allclose(orbit2.state, settled, atol=1e-6)
    assert bool(orbit2.stable) and orbit2.n_periods == 2
    # A genuine period-2 orbit: one period does not map it onto itself.
    assert abs(float(xs[-1, -1] - xs[-1, -2])) > 1e-2


BSFS_FORCE_N = 3000.0


@pytest.fixture(scope="module")
def bsfs_branch():
    params = preset("default")
    family = bsfs_family(params, BSFS_FORCE_N)
    # Steady state of `simulate` from rest: |mu| ~ 0.92 per period, 0.92^150 ~ 4e-6.
    traj = simulate(params, frequency_hz=1100.0, force_n=BSFS_FORCE_N, transient_periods=150,
                    periods=1, samples_per_period=512)
    branch = continue_orbits(family, traj.final_state, 1100.0, 1130.0, ds=0.1,
                             amplitude_index=2)
    return traj, branch


def test_bsfs_branch_matches_simulation(bsfs_branch):
    traj, branch = bsfs_branch
    assert len(branch) >= 3 and branch.p[-1] == pytest.approx(1130.0)
    assert branch.p[0] == pytest.approx(1100.0)
    assert np.all(branch.stable)  # the rising resonant branch below the fold (~1300 Hz)
    assert np.all(np.diff(branch.amplitude) > 0)  # amplitude grows towards resonance
    assert np.all(np.diff(branch.p) > 0)
    # The orbit found at 1100 Hz is the attractor `simulate` settles on: same state at
    # t = kT and the same half peak-to-peak nut amplitude (the simulation's 512 samples per
    # period resolve the extremes to ~2e-5; the branch refines them between samples).
    amp_sim = float(traj.amplitude(2))
    assert amp_sim == pytest.approx(float(branch.amplitude[0]), rel=1e-4)
    scale = np.abs(branch.states[0]).max()
    np.testing.assert_allclose(np.asarray(traj.final_state), branch.states[0], rtol=0,
                               atol=1e-4 * scale)
    assert amp_sim > 50e-6  # a strongly nonlinear regime (~100 um), not a trivial orbit


def test_cli_continue(tmp_path, bsfs_branch):
    from bsfs_jax.cli import main

    out = tmp_path / "cont"
    code = main(["continue", "--start", "1100", "--stop", "1115", "--force",
                 str(BSFS_FORCE_N), "--ds", "0.1", "--transient-periods", "150",
                 "--method", "shooting", "--no-progress", "--out", str(out)])
    assert code == 0
    for name in ("frc.png", "branch.csv", "bifurcations.json", "summary.json"):
        assert (out / name).stat().st_size > 0, name
    lines = [ln for ln in (out / "branch.csv").read_text().splitlines()
             if not ln.startswith("#")]
    names = lines[0].split(",")
    assert names[:2] == ["frequency_hz", "amplitude_um"] and "x_n_m" in names
    data = np.loadtxt(lines[1:], delimiter=",", ndmin=2)
    _, branch = bsfs_branch
    # Same guess and settings as the library call: the rows agree.
    assert data[0, 0] == pytest.approx(1100.0)
    assert data[0, 1] == pytest.approx(branch.amplitude[0] * 1e6, rel=1e-6)
    assert data[-1, 0] == pytest.approx(1115.0)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["points"] == len(data) and summary["force_n"] == BSFS_FORCE_N
    assert summary["method"] == "shooting" and summary["max_residual"] < 1e-6
    bifs = json.loads((out / "bifurcations.json").read_text())
    assert isinstance(bifs, list)


def test_frc_plot_segments(duffing_frc, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bsfs_jax.plotting import plot_continuation, stability_segments

    branch = duffing_frc
    folds = sorted((b for b in branch.bifurcations if b.kind == "fold"), key=lambda b: b.index)
    lines = stability_segments(branch.p, branch.amplitude, branch.stable, folds)
    assert [s for _, _, s in lines] == [True, False, True]
    # The unstable (dashed) part runs exactly from one fold to the other.
    assert lines[1][0][0] == folds[0].p and lines[1][0][-1] == folds[1].p
    assert lines[0][0][-1] == folds[0].p and lines[2][0][0] == folds[1].p
    fig = plot_continuation(branch, y_scale=1.0, x_label="Forcing frequency omega [rad/s]",
                            y_label="Amplitude of x [-]", title="Duffing FRC")
    ax = fig.axes[0]
    assert ax.get_xlabel().endswith("[rad/s]") and ax.get_title() == "Duffing FRC"
    styles = {ln.get_linestyle() for ln in ax.lines if ln.get_label() in
              ("stable", "unstable")}
    assert styles == {"-", "--"}
    fig.savefig(tmp_path / "duffing_frc.png")
    plt.close(fig)


def test_bifurcations_without_the_peaks(duffing_frc):
    """`find_peaks=False` (`bsfs map`'s rows) skips the peaks' location only: the same
    points and folds, located, and no peak."""
    family = frequency_family(**HARDENING)
    branch = continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                             vector_field=duffing, scale=jnp.ones(2), normalise=False,
                             p_scale=1.0, amplitude_index=0, find_peaks=False)
    assert duffing_frc.peaks and not branch.peaks
    assert duffing_frc.info["peaks_searched"] and not branch.info["peaks_searched"]
    np.testing.assert_allclose(branch.p, duffing_frc.p, rtol=1e-12)
    folds = [b.p for b in branch.bifurcations if b.kind == "fold" and b.located]
    assert len(folds) == 2
    np.testing.assert_allclose(folds, [b.p for b in duffing_frc.bifurcations
                                       if b.kind == "fold"], rtol=1e-12)
    assert branch.info["corrector_calls"] < duffing_frc.info["corrector_calls"]


def test_bifurcations_without_the_amplitudes(duffing_frc):
    """`amplitudes=False` (`bsfs continue`'s cross-check of the folds, its program
    prefetched as the command does it) leaves the orbits' samples out of the corrector:
    the same points and located folds, NaN amplitudes, and no peak events; asking for the
    peaks without the amplitudes is refused."""
    from bsfs_jax.solvers import Shooting, prefetch_corrector

    family = frequency_family(**HARDENING)
    kw = dict(vector_field=duffing, scale=jnp.ones(2), normalise=False, p_scale=1.0,
              find_peaks=False, amplitudes=False)
    prefetch_corrector(family, duffing, Shooting(), jnp.array([0.1, 0.0]), 0.8,
                       amplitudes=False).result(timeout=300)
    branch = continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05, **kw)
    assert branch.info["corrector_traces"] == 0  # the prefetched program
    np.testing.assert_allclose(branch.p, duffing_frc.p, rtol=1e-12)
    assert np.all(np.isnan(branch.amplitudes)) and not branch.peaks
    folds = [b.p for b in branch.bifurcations if b.kind == "fold" and b.located]
    np.testing.assert_allclose(folds, [b.p for b in duffing_frc.bifurcations
                                       if b.kind == "fold"], rtol=1e-12)
    assert {b.kind for b in branch.bifurcations} == {"fold"}
    with pytest.raises(ValueError, match="find_peaks needs the amplitudes"):
        continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                        **dict(kw, find_peaks=True))


def test_amplitudes_at_the_events_only(duffing_frc):
    """`amplitudes="events"` (`bsfs map`'s row continuations): the corrector of
    `amplitudes=False` (no new trace) and the same points, NaN amplitudes along the branch,
    and each located fold's amplitudes from a program of their own, equal to those the
    full corrector gives there; any other value is refused."""
    from bsfs_jax.solvers import Shooting, prefetch_corrector

    family = frequency_family(**HARDENING)
    kw = dict(vector_field=duffing, scale=jnp.ones(2), normalise=False, p_scale=1.0,
              find_peaks=False)
    prefetch_corrector(family, duffing, Shooting(), jnp.array([0.1, 0.0]), 0.8,
                       amplitudes="events").result(timeout=300)
    branch = continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                             amplitudes="events", **kw)
    assert branch.info["corrector_traces"] == 0
    np.testing.assert_allclose(branch.p, duffing_frc.p, rtol=1e-12)
    assert np.all(np.isnan(branch.amplitudes))
    folds = [b for b in branch.bifurcations if b.kind == "fold"]
    full = [b for b in duffing_frc.bifurcations if b.kind == "fold"]
    assert len(folds) == len(full) == 2 and all(b.located for b in folds)
    for b, ref in zip(folds, full, strict=True):
        assert b.p == pytest.approx(ref.p, rel=1e-12)
        assert np.all(np.isfinite(b.amplitudes)) and b.amplitude == b.amplitudes[0]
        np.testing.assert_allclose(b.amplitudes, ref.amplitudes, rtol=1e-10)
        np.testing.assert_array_equal(b.point.amplitudes, b.amplitudes)
    with pytest.raises(ValueError, match="amplitudes must be True, False or 'events'"):
        continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                        **dict(kw, amplitudes="all"))


def test_a_brief_continuation_compiles_for_quick_compilation(duffing_frc):
    """`brief=True` (a few dozen corrector calls: `bsfs continue`'s cross-check) compiles
    shooting's corrector without XLA's newer CPU fusion emitters, which every other
    shooting corrector gets (`runs_long`) and harmonic balance's never does; it is a
    program of its own (traced anew) and follows the same branch to rounding."""
    from bsfs_jax._programs import RUNS_LONG
    from bsfs_jax.solvers import Shooting
    from bsfs_jax.solvers._kernel import _options

    emitters = next(iter(RUNS_LONG))
    assert _options(Shooting()).get(emitters) is True
    assert emitters not in _options(Shooting(), brief=True)
    assert emitters not in _options(HarmonicBalance()) | _options(HarmonicBalance(), True)
    family = frequency_family(**HARDENING)
    branch = continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                             vector_field=duffing, scale=jnp.ones(2), normalise=False,
                             p_scale=1.0, amplitude_index=0, brief=True)
    assert branch.info["corrector_traces"] >= 1
    assert len(branch.p) == len(duffing_frc.p)
    np.testing.assert_allclose(branch.p, duffing_frc.p, rtol=1e-10)
    np.testing.assert_allclose(branch.amplitudes, duffing_frc.amplitudes, rtol=1e-8)
    folds = [b.p for b in branch.bifurcations if b.kind == "fold"]
    assert folds == pytest.approx([b.p for b in duffing_frc.bifurcations
                                   if b.kind == "fold"], rel=1e-10)


def test_steps_that_follow_the_turn_find_the_same_folds(duffing_frc):
    """`angle_target` (`bsfs map`'s rows): step lengths from the tangent's turn, up to a
    far larger ds_max, reach the end of the interval with no corrector rejections beyond
    a few, every accepted step turning by at most max_angle, and locate the same two
    folds as the default rule (regula falsi to its tolerance, so the locations agree far
    below the steps' size); a target outside (0, max_angle) is refused."""
    family = frequency_family(**HARDENING)
    kw = dict(vector_field=duffing, scale=jnp.ones(2), normalise=False, p_scale=1.0,
              amplitude_index=0)
    branch = continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                             ds_max=5.0, angle_target=0.25, max_angle=0.4, **kw)
    assert branch.info["stop_reason"] == "left the parameter interval"
    assert branch.info["steps"] < duffing_frc.info["steps"]
    assert branch.info["rejected"] < duffing_frc.info["rejected"]
    folds = sorted((b for b in branch.bifurcations if b.kind == "fold"), key=lambda b: b.p)
    ref = sorted((b for b in duffing_frc.bifurcations if b.kind == "fold"),
                 key=lambda b: b.p)
    assert len(folds) == len(ref) == 2 and all(b.located for b in folds)
    for b, r in zip(folds, ref, strict=True):
        assert b.p == pytest.approx(r.p, rel=1e-7)
        assert b.amplitude == pytest.approx(r.amplitude, rel=1e-6)
    with pytest.raises(ValueError, match="angle_target must lie in"):
        continue_orbits(family, jnp.array([0.1, 0.0]), 0.8, 1.3, ds=0.05,
                        angle_target=0.5, max_angle=0.4, **kw)


def test_event_location_stops_at_the_test_functions_noise_floor(monkeypatch):
    """Regula falsi on a fold's test function g = dp/ds whose values carry noise above
    1e-6 of their size at the bracket's ends (a converged orbit's tangent carries the
    corrector tolerance's noise): it stops once |g| is at the noise floor and has stalled,
    returns the point of smallest |g| met (not the last), and counts it located; without
    the floor rule the same search goes on chasing the noise."""
    from bsfs_jax.solvers import _events
    from bsfs_jax.solvers._branch import HostPoint
    from bsfs_jax.solvers._events import _illinois

    def point(h, g):
        return HostPoint(u=np.array([h, 0.0]), tangent=np.array([1.0, g]), jacobian=None,
                         residual=0.0, steps=1, ok=True, mu=np.array([0.5, 0.2]),
                         amplitudes=np.zeros(1), slope=0.0, error=0.0, accurate=True,
                         state=np.zeros(1), ds_used=h)

    class Noisy:
        """g(h) = 1e-6 (0.3 - h) (1 + 3 h^2) + noise, h the offset along u[0]."""

        def __init__(self, noise):
            self.rng, self.noise, self.calls = np.random.default_rng(7), noise, 0

        def correct(self, u_pred, tangent, ds_used=0.0, chord=None):
            self.calls += 1
            h = float(u_pred[0])
            return point(h, 1e-6 * (0.3 - h) * (1.0 + 3.0 * h * h)
                         + self.noise * self.rng.standard_normal())

    before, after = point(0.0, 3e-7), point(1.0, -2.8e-6)
    quiet = Noisy(5e-11)  # 2e-5 of |g| at the ends: above 1e-6, below the floor
    best, located = _illinois(quiet, before, after, 0, 40)
    assert located and quiet.calls <= 10
    assert best.u[0] == pytest.approx(0.3, abs=1e-3)
    assert abs(best.tangent[-1]) <= 1e-4 * 2.8e-6
    monkeypatch.setattr(_events, "NOISE_FLOOR", 0.0)
    chasing = Noisy(5e-11)
    _illinois(chasing, before, after, 0, 40)
    assert chasing.calls > quiet.calls
