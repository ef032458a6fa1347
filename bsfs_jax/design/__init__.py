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

from typing import TYPE_CHECKING

from .._lazy import lazy_names

if TYPE_CHECKING:
    from ._catalogue import DEFAULT_FORCE_N as DEFAULT_FORCE_N
    from ._catalogue import DEFAULT_FREQUENCY_HZ as DEFAULT_FREQUENCY_HZ
    from ._catalogue import DESIGN_PARAMETERS as DESIGN_PARAMETERS
    from ._catalogue import METRIC_INFO as METRIC_INFO
    from ._catalogue import MetricInfo as MetricInfo
    from ._crosscheck import PAPER_TRENDS as PAPER_TRENDS
    from ._crosscheck import crosscheck_markdown as crosscheck_markdown
    from ._crosscheck import paper_crosscheck as paper_crosscheck
    from ._gradcheck import FD_TOLERANCE as FD_TOLERANCE
    from ._gradcheck import check_gradient as check_gradient
    from ._gradcheck import compare_gradients as compare_gradients
    from ._gradcheck import probe_gradient as probe_gradient
    from ._metrics import METRICS as METRICS
    from ._metrics import Metric as Metric
    from ._metrics import OperatingPoint as OperatingPoint
    from ._metrics import frc_peak_location as frc_peak_location
    from ._metrics import frf_peak_frequency as frf_peak_frequency
    from ._metrics import get_metric as get_metric
    from ._optimize import OptimizationResult as OptimizationResult
    from ._optimize import default_bounds as default_bounds
    from ._optimize import optimize as optimize
    from ._optimize import verify_by_simulation as verify_by_simulation
    from ._orbit import OrbitSettings as OrbitSettings
    from ._orbit import locate_frc_peak as locate_frc_peak
    from ._orbit import opens_joint as opens_joint
    from ._orbit import periodic_orbit as periodic_orbit
    from ._sensitivity import SensitivityResult as SensitivityResult
    from ._sensitivity import compiled as compiled
    from ._sensitivity import evaluate as evaluate
    from ._sensitivity import finite_difference_sensitivities as finite_difference_sensitivities
    from ._sensitivity import sensitivities as sensitivities
    from ._sensitivity import with_values as with_values

_LAZY = {
    "PAPER_TRENDS": "._crosscheck",
    "crosscheck_markdown": "._crosscheck",
    "paper_crosscheck": "._crosscheck",
    "FD_TOLERANCE": "._gradcheck",
    "check_gradient": "._gradcheck",
    "compare_gradients": "._gradcheck",
    "probe_gradient": "._gradcheck",
    "METRICS": "._metrics",
    "Metric": "._metrics",
    "OperatingPoint": "._metrics",
    "frc_peak_location": "._metrics",
    "frf_peak_frequency": "._metrics",
    "get_metric": "._metrics",
    "OptimizationResult": "._optimize",
    "default_bounds": "._optimize",
    "optimize": "._optimize",
    "verify_by_simulation": "._optimize",
    "OrbitSettings": "._orbit",
    "locate_frc_peak": "._orbit",
    "opens_joint": "._orbit",
    "periodic_orbit": "._orbit",
    "DEFAULT_FORCE_N": "._catalogue",
    "DEFAULT_FREQUENCY_HZ": "._catalogue",
    "DESIGN_PARAMETERS": "._catalogue",
    "METRIC_INFO": "._catalogue",
    "MetricInfo": "._catalogue",
    "SensitivityResult": "._sensitivity",
    "compiled": "._sensitivity",
    "evaluate": "._sensitivity",
    "finite_difference_sensitivities": "._sensitivity",
    "sensitivities": "._sensitivity",
    "with_values": "._sensitivity",
}

__all__ = list(_LAZY)

__getattr__, __dir__ = lazy_names(__name__, _LAZY)
