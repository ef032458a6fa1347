"""Per-speed thermal offsets (`--fit d_n,d_b`): one D_n and one D_b per spindle speed,
recovered from stepped sines at three speeds of the bundled synthetic set.

The prior's thermal expansion is 1.5 x the truth's, so every prior offset is off by about
50 %; the fit must bring each speed's offsets back to the truth's (data/truth.toml) within
the stated errors, and the records must determine them.
"""

import numpy as np

import bsfs_jax
import identification as idn


def test_per_speed_offsets_are_recovered():
    truth = bsfs_jax.load_params(idn.DATA_DIR / "truth.toml")
    paths = [p for p in idn.bundled_records("stepped-sine")
             if "_100n_" in str(p) and ("0150hz" in str(p) or "0950hz" in str(p))]
    assert len(paths) == 6  # 150 and 950 Hz at 1000, 2000 and 3000 r/min
    prior = truth.replace("thermal.expansion_per_k",
                          1.5 * float(truth.get("thermal.expansion_per_k")))
    res = idn.identify(paths, prior, ("d_n", "d_b"), profile=False)
    u = res.uncertainty
    assert res.fit.converged
    assert u.names == ("d_n@1000rpm", "d_n@2000rpm", "d_n@3000rpm",
                       "d_b@1000rpm", "d_b@2000rpm", "d_b@3000rpm")
    # The truth's offsets per speed (um), from its thermal chain at each speed.
    true_values = idn.Problem(res.data, truth, ("d_n", "d_b")).prior_values
    start = res.problem.prior_values
    assert np.all(np.abs(start - true_values) > 5 * u.std)  # the prior is far off
    z = (u.values - true_values) / u.std
    assert np.all(np.abs(z) < 3.0), z
    assert np.all(u.determined)
    # Offsets grow with speed (more friction heat), as the truth's do.
    for joint in (slice(0, 3), slice(3, 6)):
        assert np.all(np.diff(u.values[joint]) > 0)
