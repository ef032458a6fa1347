"""Design: response metrics, their exact sensitivities and gradient-based optimisation.

Metrics are differentiable functions of `BallScrewParams` (see `METRICS`): orbit metrics
are differentiated by the implicit function theorem through the periodic orbit, static
ones through the Newton equilibrium and the modal eigenproblem. Parameters are named
by their TOML vocabulary ("nut.balls", "thermal.speed_rpm", ...), in file units.

    from bsfs_jax import preset
    from bsfs_jax.design import sensitivities, optimize
    s = sensitivities("amplitude", preset(), frequency_hz=120.0, force_n=100.0)
    print(s.table_markdown())
"""

from ._crosscheck import PAPER_TRENDS as PAPER_TRENDS
from ._crosscheck import crosscheck_markdown as crosscheck_markdown
from ._crosscheck import paper_crosscheck as paper_crosscheck
from ._gradcheck import FD_TOLERANCE as FD_TOLERANCE
from ._gradcheck import check_gradient as check_gradient
from ._gradcheck import compare_gradients as compare_gradients
from ._gradcheck import gradient_not_checked as gradient_not_checked
from ._gradcheck import largest_entries as largest_entries
from ._gradcheck import probe_gradient as probe_gradient
from ._metrics import METRICS as METRICS
from ._metrics import Metric as Metric
from ._metrics import OperatingPoint as OperatingPoint
from ._metrics import frc_peak_location as frc_peak_location
from ._metrics import frf_peak_frequency as frf_peak_frequency
from ._metrics import get_metric as get_metric
from ._optimize import OptimizationResult as OptimizationResult
from ._optimize import OptimizationStart as OptimizationStart
from ._optimize import default_bounds as default_bounds
from ._optimize import optimization_start as optimization_start
from ._optimize import optimize as optimize
from ._optimize import verify_by_simulation as verify_by_simulation
from ._orbit import OPENS_FRACTION as OPENS_FRACTION
from ._orbit import OrbitSettings as OrbitSettings
from ._orbit import PeakHint as PeakHint
from ._orbit import fold_frequency_value as fold_frequency_value
from ._orbit import frc_peak_frequency_value as frc_peak_frequency_value
from ._orbit import frc_peak_value as frc_peak_value
from ._orbit import frc_point_values as frc_point_values
from ._orbit import locate_frc_peak as locate_frc_peak
from ._orbit import opens_joint as opens_joint
from ._orbit import peak_orbit_samples as peak_orbit_samples
from ._orbit import periodic_orbit as periodic_orbit
from ._orbit import point_hint as point_hint
from ._sensitivity import DEFAULT_FORCE_N as DEFAULT_FORCE_N
from ._sensitivity import DEFAULT_FREQUENCY_HZ as DEFAULT_FREQUENCY_HZ
from ._sensitivity import DESIGN_PARAMETERS as DESIGN_PARAMETERS
from ._sensitivity import SensitivityResult as SensitivityResult
from ._sensitivity import check_design_inputs as check_design_inputs
from ._sensitivity import compiled as compiled
from ._sensitivity import evaluate as evaluate
from ._sensitivity import finite_difference_sensitivities as finite_difference_sensitivities
from ._sensitivity import sensitivities as sensitivities
from ._sensitivity import with_values as with_values
