"""Records near a fold: two stable orbits at one frequency and force.

The bundled through-resonance drive (data/resonance.toml) has, at 100 N, two stable orbits
between its folds at 1101.2 and 1103.6 Hz (`bsfs continue --params data/resonance.toml
--start 1000 --stop 1300 --force 100`). A stepped sine at 1102.5 Hz reaches one of them
sweeping up and the other sweeping down.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import bsfs_jax
import identification as idn
from identification.measurement._orbit_model import branches, nonlinear_acceleration

FREQUENCY = 1102.5


@pytest.fixture(scope="module")
def swept_records():
    truth = bsfs_jax.load_params(idn.DATA_DIR / "resonance.toml")
    # A controlled shaker (no amplitude drift) and a settling time long enough near the
    # fold, where the slowest Floquet multiplier approaches 1.
    effects = idn.TestEffects(drift=0.0, settle_s=1.0)
    data = {sweep: idn.harmonic_analysis(idn.synthesize(truth, FREQUENCY, 100.0, seed=5,
                                                        sweep=sweep, effects=effects))
            for sweep in ("up", "down")}
    return bsfs_jax.build_system(truth), data


def test_sweep_direction_is_in_the_header(swept_records):
    _, data = swept_records
    assert data["up"].record.meta["sweep"] == "up"
    assert data["down"].record.meta["sweep"] == "down"
    with pytest.raises(ValueError, match="sweep"):
        idn.synthesize(bsfs_jax.preset(), 500.0, 100.0, sweep="sideways")
    # A drive whose first mode is at ~0 Hz gave a plan with sines at 0 Hz, which failed as
    # "no periodic orbit ... at 0 Hz"; a frequency outside the band is now refused first.
    for f in (0.0, 5000.0):
        with pytest.raises(ValueError, match="0 < frequency_hz < 0.4 x the sample rate"):
            idn.synthesize(bsfs_jax.preset(), f, 100.0, sweep="up")


def test_each_record_is_labelled_with_the_branch_it_is_on(swept_records):
    system, data = swept_records
    ds = [data["up"], data["down"]]
    args = ([d.frequency_hz for d in ds], np.stack([d.force for d in ds]),
            np.stack([d.acceleration for d in ds]))
    for sweep in (None, [1.0, -1.0]):  # from the measured state, and from the header
        labels, evidence, _, _ = branches(system, *args, sweep)
        # Sweeping up, the drive stays on the low-amplitude orbit up to the upper fold.
        assert labels == ["lower", "upper"]
        assert [e["sweep_reaching_it"] for e in evidence] == ["up", "down"]
        assert all(e["fitted_stable"] for e in evidence)
        assert evidence[1]["fitted_amplitude_m_s2"] > 1.5 * evidence[0]["fitted_amplitude_m_s2"]


def test_the_model_fits_each_record_on_its_own_branch(swept_records):
    system, data = swept_records
    orbits = {}
    for sweep, d in data.items():
        a, ok = nonlinear_acceleration(system, d.frequency_hz, jnp.asarray(d.force),
                                       jnp.asarray(d.acceleration))
        assert bool(ok)
        orbits[sweep] = np.asarray(a)
    for sweep, d in data.items():
        other = "down" if sweep == "up" else "up"
        se = np.sqrt(d.acceleration_var[0])
        z_own = np.max(np.abs([(orbits[sweep][0] - d.acceleration[0]).real / se[0],
                               (orbits[sweep][0] - d.acceleration[0]).imag / se[1]]))
        z_other = np.abs(orbits[other][0] - d.acceleration[0]) / np.max(se)
        # at the truth, the record's own orbit is within a few standard errors (the fold's
        # sensitivity to the shaker's harmonic distortion remains); the other is hundreds off
        assert z_own < 6.0
        assert z_other > 100.0


@pytest.mark.parametrize("frequency", [1099.0, 1106.0])
def test_a_sweep_past_a_fold_jumps_to_the_orbit_that_remains(frequency):
    """Below the lower fold (1101.2 Hz) a down-sweep has left the upper branch, above the
    upper fold (1103.6 Hz) an up-sweep has left the lower one: each jumps, as a stepped sine
    does, and lands on the only orbit there, the one the other sweep reaches continuously."""
    from identification.measurement._orbit_model import acceleration_of, swept_orbit

    system = bsfs_jax.build_system(bsfs_jax.load_params(idn.DATA_DIR / "resonance.toml"))
    fc = jnp.asarray([-100j])
    up, down = (swept_orbit(system, frequency, fc, d) for d in (1.0, -1.0))
    assert bool(up.converged) and bool(down.converged)
    assert bool(up.stable) and bool(down.stable)
    a_up, a_down = (np.asarray(acceleration_of(o, frequency, 1))[0] for o in (up, down))
    assert abs(a_up - a_down) < 1e-6 * abs(a_down)


def test_a_record_started_between_the_branches_is_not_labelled_with_one():
    """A measured state between the two stable orbits leads Newton to the unstable middle
    orbit: no record can stay there, and the label says unresolved, not a branch."""
    from identification.measurement._orbit_model import acceleration_of, swept_orbit

    system = bsfs_jax.build_system(bsfs_jax.load_params(idn.DATA_DIR / "resonance.toml"))
    fc = np.asarray([-100j])
    up, down = (np.asarray(acceleration_of(swept_orbit(system, FREQUENCY, jnp.asarray(fc), d),
                                           FREQUENCY, 1))[0] for d in (1.0, -1.0))
    labels, evidence, _, _ = branches(system, [FREQUENCY], fc[None],
                                   np.asarray([[up + 0.6 * (down - up)]]))
    assert not evidence[0]["fitted_stable"]
    assert abs(up) < evidence[0]["fitted_amplitude_m_s2"] < abs(down)
    assert labels == ["unresolved"]


@pytest.fixture(scope="module")
def swept_problem(swept_records):
    _, data = swept_records
    truth = bsfs_jax.load_params(idn.DATA_DIR / "resonance.toml")
    return idn.Problem([data["up"], data["down"]], truth, ("c_n",), model="nonlinear")


def _swap_records(pb, rows):
    """`rows` (one per sine row of the group) with the two records' rows swapped (the
    group's rows are padded: `_groups.MIN_SINE_ROWS`)."""
    rows = np.array(rows)
    a, b = (pb.layout[i][3] for i in (0, 1))
    rows[[a, b]] = rows[[b, a]]
    return rows


def test_swept_records_start_from_their_sweeps_orbit(swept_problem, swept_records):
    """In the fit a swept record's orbit starts from its anchor, the orbit its sweep
    reaches (`_anchors.py`), not from its measured state: with the headers swapped the
    model of each record is the other branch, hundreds of standard errors off."""
    from identification.measurement._anchors import anchored, same_orbits

    pb = swept_problem
    assert pb.structure.sweeps
    theta = np.zeros(pb.n_params)
    own = pb.anchored(theta)
    model = own.model_harmonics(theta)
    for d, m in zip(pb.data, model):
        se = np.sqrt(d.acceleration_var[0])
        assert np.max(np.abs([(m[0] - d.acceleration[0]).real / se[0],
                              (m[0] - d.acceleration[0]).imag / se[1]])) < 6.0
    # the anchors swapped between the two records: each record's model is the other orbit
    (g,) = own.fit_data.groups
    swapped = own.with_fit_data(eqx.tree_at(
        lambda d: d.groups, own.fit_data,
        (eqx.tree_at(lambda x: x.sine_anchor, g, _swap_records(pb, g.sine_anchor)),)))
    other = swapped.model_harmonics(theta)
    for d, m in zip(pb.data, other):
        assert np.abs(m[0] - d.acceleration[0]) / np.max(np.sqrt(d.acceleration_var[0])) > 100
    assert same_orbits(theta, own.fit_data, anchored(own.fit_data, theta, pb.structure),
                       pb.structure)
    assert not same_orbits(theta, swapped.fit_data, own.fit_data, pb.structure)


def test_a_lane_on_a_stale_anchor_is_solved_again(swept_problem):
    """`settle` re-anchors a lane whose fitted orbit is not the one its sweep reaches at
    its result, and solves it again from there."""
    from identification.measurement._anchors import settle

    pb = swept_problem
    theta = np.zeros((1, pb.n_params))
    own = pb.anchored(theta[0]).fit_data
    (g,) = own.groups
    stale = eqx.tree_at(lambda d: d.groups, own,
                        (eqx.tree_at(lambda x: x.sine_anchor, g,
                                     _swap_records(pb, g.sine_anchor)),))
    calls = []

    def resolve(th, ds):
        calls.append(ds)
        return dict(theta=th, cost=np.ones(len(ds)), steps=np.full(len(ds), 2),
                    stop=["again"] * len(ds))

    out = dict(theta=theta.copy(), cost=np.ones(1), steps=np.full(1, 5), stop=["first"])
    datas = [stale]
    assert settle(out, datas, pb.structure, resolve) == [True]
    assert len(calls) == 1 and out["steps"][0] == 7 and out["stop"] == ["again"]
    np.testing.assert_array_equal(np.asarray(datas[0].groups[0].sine_anchor),
                                  np.asarray(g.sine_anchor))


def test_a_fit_of_swept_records_lands_on_their_branches(swept_problem):
    """From quasi-random starts, a fit of the damping on the two records at the fold
    converges, with each record on its own branch."""
    from identification.fitting._check import record_branches

    pb = swept_problem
    res = idn.fit(pb, starts=4, seed=1)
    assert res.converged, res.convergence_text
    assert all(run.get("on_swept_orbit") for run in res.starts if run["same_minimum"])
    labels = record_branches(res.problem, res.theta)
    assert [labels[i]["branch"] for i in (0, 1)] == ["lower", "upper"]
    truth = pb.values(np.zeros(1))[0]
    sigma = np.sqrt(np.linalg.inv(res.jacobian.T @ res.jacobian)[0, 0]) * truth
    assert abs(res.values[0] - truth) < 4 * sigma



def _study_drive(**truth):
    """A drive of the preload robustness study: the default preset at 2000 r/min with the
    fitted parameters' true values (`scripts/robustness_study.py`, `--draw prior`)."""
    p = bsfs_jax.preset().replace("thermal.speed_rpm", 2000.0)
    for name, v in truth.items():
        p = p.replace(idn.FIT_PARAMETERS[name].key, v)
    return bsfs_jax.build_system(p)

def test_a_lightly_damped_up_sweep_follows_its_upper_branch_to_the_fold():
    """Drive 267 of the preload robustness study (damping ratio 0.26 % at 1091 Hz, a
    hardening resonance): sweeping up, a stepped sine stays on the upper orbit far past the
    linear resonance. The sweep with a fixed step of 1/24 of its span lost that branch
    (1140 Hz: 410 m/s^2, the down-sweep's orbit) and the fit, matching a 5.8 km/s^2 record
    with a 0.56 km/s^2 model, returned c_b at 7.6 times its truth. The reference: natural
    continuation over the same span in 400 fixed steps (0.29 Hz, 1/20 of the half-power
    bandwidth), each from the last orbit it converged to (near 1050 Hz, where contact loss
    sets in, Newton fails for a few steps and the next converges higher up the branch)."""
    from identification.measurement._orbit_model import (
        SWEEP_SPAN,
        acceleration_of,
        orbit_of,
        swept_orbit,
    )

    system = _study_drive(nut_preload=1306.6395169721436, bearing_preload=843.6326718231628,
                          c_b=291.44685596464143, c_s=111.50394916691158,
                          c_n=1369.3012411083357)
    f, fc = 1140.0, jnp.asarray([100.0 + 0j])
    up, down = (swept_orbit(system, f, fc, d) for d in (1.0, -1.0))
    a_up, a_down = (abs(np.asarray(acceleration_of(o, f, 1))[0]) for o in (up, down))
    assert bool(up.converged) and bool(up.stable) and bool(down.stable)

    import jax

    from identification.measurement._orbit_model import _unknowns, linear_harmonics

    fs = f * (1.0 - SWEEP_SPAN * (1.0 - jnp.arange(401) / 400))
    z0 = _unknowns(linear_harmonics(system, fs[0], fc), fs[0], 16)

    def step(z, fk):
        o = orbit_of(system, fk, fc, z)
        return jnp.where(o.converged, o.unknowns, z), o.converged

    z, ok = jax.jit(lambda z0: jax.lax.scan(step, z0, fs))(z0)
    assert bool(ok[-1]) and int(jnp.sum(ok)) > 380
    ref = abs(np.asarray(acceleration_of(orbit_of(system, f, fc, z), f, 1))[0])
    assert abs(a_up - ref) < 1e-6 * ref
    assert a_up > 5.0 * a_down  # the upper orbit, not the one the down-sweep reaches


@pytest.mark.parametrize("frequency", [1090.0, 1119.7])
def test_past_a_hardening_fold_the_up_sweep_lands_on_the_orbit_that_remains(frequency):
    """Drive 262 of the preload robustness study: the up-sweep's upper branch folds near
    1088 Hz, at the linear resonance. Past it the orbit that remains (the down-sweep's) is
    a quarter of the linear response; the sweep jumps there, and where no start converges
    at one frequency it jumps again a step further on (a sweep that instead crept on in
    its smallest step ran out of solves, and the synthesis said 'no periodic orbit')."""
    from identification.measurement._orbit_model import acceleration_of, swept_orbit

    system = _study_drive(nut_preload=1433.246631862498, bearing_preload=814.6446398656908,
                          c_b=780.8600440859817, c_s=128.13901611273874,
                          c_n=3192.865061743776)
    fc = jnp.asarray([100.0 + 0j])
    up, down = (swept_orbit(system, frequency, fc, d) for d in (1.0, -1.0))
    assert bool(up.converged) and bool(down.converged) and bool(up.stable)
    a_up, a_down = (abs(np.asarray(acceleration_of(o, frequency, 1))[0]) for o in (up, down))
    assert abs(a_up - a_down) < 1e-6 * a_down
