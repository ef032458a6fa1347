"""The NUTS posterior check (`identification.posterior`, `bsfs identify --posterior`).

On the preload-loss records every parameter is determined and the posterior is close to
Gaussian in log-values, so a converged sample must reproduce the linearised means and
standard errors. The CLI's input checks are named cases in test_cli.py.
"""

import numpy as np
import pytest

import identification as idn
from identification.intervals._posterior import RHAT_MAX


@pytest.fixture(scope="module")
def preload_fit():
    return idn.identify(idn.bundled_records("preload-loss"), None, idn.PRELOAD_FIT,
                        starts=1, profile=False)


def test_nuts_reproduces_the_linearised_posterior_where_it_is_gaussian(preload_fit):
    res = preload_fit
    u = res.uncertainty
    post = idn.posterior(res.fit, u, samples=300, warmup=300, chains=2, seed=1)
    assert post.converged, (post.rhat, post.ess, post.divergences)
    assert post.samples.shape == (2, 300, len(u.names))
    assert np.all(post.rhat < RHAT_MAX)
    # Means within a fifth of a standard error (the sampling error of ~600 effective
    # draws is 0.04 sigma), spreads within 15 %.
    assert np.all(np.abs(post.mean - u.values) < 0.2 * u.std), (post.mean, u.values)
    assert np.all(np.abs(post.std / u.std - 1.0) < 0.15), post.std / u.std
    d = post.as_dict()
    assert set(d["parameters"]) == set(u.names) and d["converged"]
    text = idn.posterior_text(d, idn.report_dict(res))
    assert text.startswith("Posterior by NUTS") and "converged (" in text


def test_posterior_refuses_without_priors_and_with_orbit_records(preload_fit):
    data = preload_fit.data
    ml = idn.Problem(data, preload_fit.problem.prior, idn.PRELOAD_FIT, priors=None,
                     model="linear")
    res = idn.fit(ml, starts=1, check_models=False)
    with pytest.raises(ValueError, match="needs priors"):
        idn.posterior(res, idn.uncertainty(res))
