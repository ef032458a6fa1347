"""The fit: the identification problem, its solver and its starts.

- `Problem(data, prior, fit_names, model=..., priors=...)`: the records' data, the
  parameters to fit (`FIT_PARAMETERS`, `DEFAULT_FIT`, `PRELOAD_FIT`, `parse_fit`), their
  priors (`parse_priors`) and the measurement model chosen per record;
- `fit(problem, starts=..., seed=...)` -> `FitResult`: the maximum a posteriori estimate
  theta (p,) from quasi-random and modal starts, each solved by optimistix (`solve`,
  `SolveOptions`; batched lanes, `solved_lanes`), with the fit's convergence evidence;
- `check_model(result)`, `prefetch_check(problem)`: the model at the estimate checked
  (branches of the periodic-orbit records, truncation, the records' misfit);
- `informative(...)`, `NO_INFORMATION_STD`: which parameters the data inform.
"""

from ._check import check_model as check_model
from ._check import prefetch_check as prefetch_check
from ._fit import STEP_TOL as STEP_TOL
from ._fit import FitResult as FitResult
from ._fit import fit as fit
from ._fit import full_used_mask as full_used_mask
from ._fit import remaining_step as remaining_step
from ._fit import solved_lanes as solved_lanes
from ._fit import start_points as start_points
from ._lm import NO_INFORMATION_STD as NO_INFORMATION_STD
from ._lm import informative as informative
from ._parameters import DEFAULT_FIT as DEFAULT_FIT
from ._parameters import FIT_PARAMETERS as FIT_PARAMETERS
from ._parameters import PRELOAD_FIT as PRELOAD_FIT
from ._parameters import parse_fit as parse_fit
from ._parameters import parse_priors as parse_priors
from ._problem import Problem as Problem
from ._solve import SolveOptions as SolveOptions
from ._solve import solve as solve
