"""Uncertainty of a fit: intervals for every fitted parameter.

- `uncertainty(result)` -> `Uncertainty`: the linearised covariance (p, p) in the fit's
  coordinates, standard errors in file units, determined or prior-dominated per parameter
  (`DETERMINED_RATIO`, `IDENTIFIABLE_STD`);
- `profile_intervals(result, ...)`: profile-likelihood checks of the linearised intervals;
- `refit(result, n)` -> `Refits` (`REFITS`, `refits_by_default`, `refits_for`,
  `save_refits`): randomised-maximum-likelihood refits;
- `posterior(result)` -> `Posterior` (NUTS with blackjax; `MIN_DRAWS`, `posterior_text`).
"""

from ._posterior import MIN_DRAWS as MIN_DRAWS
from ._posterior import Posterior as Posterior
from ._posterior import posterior as posterior
from ._posterior import posterior_text as posterior_text
from ._profile import profile_intervals as profile_intervals
from ._refits import REFITS as REFITS
from ._refits import Refits as Refits
from ._refits import refit as refit
from ._refits import refits_by_default as refits_by_default
from ._refits import refits_for as refits_for
from ._refits import save_refits as save_refits
from ._uncertainty import DETERMINED_RATIO as DETERMINED_RATIO
from ._uncertainty import IDENTIFIABLE_STD as IDENTIFIABLE_STD
from ._uncertainty import Uncertainty as Uncertainty
from ._uncertainty import uncertainty as uncertainty
