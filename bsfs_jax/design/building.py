"""Building blocks of the design package that other bsfs packages compose: following a
frequency-response point or peak from a start (the forecast's draws), peak hints, the
sensitivity programs' prefetch, input checks. Not a user API: their
signatures follow what those packages need and may change between versions; users call
`bsfs_jax.design` (`sensitivities`, `optimize`, `locate_frc_peak`, ...)."""

from typing import TYPE_CHECKING

from .._lazy import lazy_names

if TYPE_CHECKING:
    from ._frc_follow import follow_point as follow_point
    from ._frc_follow import follow_start as follow_start
    from ._frc_follow import follow_start_and_gradient as follow_start_and_gradient
    from ._frc_follow import follow_to as follow_to
    from ._frc_follow import orbit_samples_at as orbit_samples_at
    from ._gradcheck import gradient_not_checked as gradient_not_checked
    from ._gradcheck import largest_entries as largest_entries
    from ._optimize import OptimizationStart as OptimizationStart
    from ._optimize import optimization_start as optimization_start
    from ._orbit import OPENS_FRACTION as OPENS_FRACTION
    from ._orbit import PeakHint as PeakHint
    from ._orbit import fold_frequency_value as fold_frequency_value
    from ._orbit import frc_peak_frequency_value as frc_peak_frequency_value
    from ._orbit import frc_peak_value as frc_peak_value
    from ._orbit import frc_point_values as frc_point_values
    from ._orbit import linear_guess as linear_guess
    from ._orbit import locate_frc_peak_near as locate_frc_peak_near
    from ._orbit import peak_hint_layout as peak_hint_layout
    from ._orbit import peak_orbit_samples as peak_orbit_samples
    from ._orbit import point_hint as point_hint
    from ._sensitivity import check_design_inputs as check_design_inputs
    from ._sensitivity import locate_hint as locate_hint
    from ._sensitivity import parameter_values as parameter_values
    from ._sensitivity import prefetch_programs as prefetch_programs

_LAZY = {
    "linear_guess": "bsfs_jax.design._orbit",
    "locate_hint": "bsfs_jax.design._sensitivity",
    "parameter_values": "bsfs_jax.design._sensitivity",
    "follow_point": "bsfs_jax.design._frc_follow",
    "follow_start": "bsfs_jax.design._frc_follow",
    "follow_start_and_gradient": "bsfs_jax.design._frc_follow",
    "follow_to": "bsfs_jax.design._frc_follow",
    "orbit_samples_at": "bsfs_jax.design._frc_follow",
    "gradient_not_checked": "bsfs_jax.design._gradcheck",
    "largest_entries": "bsfs_jax.design._gradcheck",
    "OptimizationStart": "bsfs_jax.design._optimize",
    "optimization_start": "bsfs_jax.design._optimize",
    "OPENS_FRACTION": "bsfs_jax.design._orbit",
    "PeakHint": "bsfs_jax.design._orbit",
    "fold_frequency_value": "bsfs_jax.design._orbit",
    "frc_peak_frequency_value": "bsfs_jax.design._orbit",
    "frc_peak_value": "bsfs_jax.design._orbit",
    "frc_point_values": "bsfs_jax.design._orbit",
    "locate_frc_peak_near": "bsfs_jax.design._orbit",
    "peak_hint_layout": "bsfs_jax.design._orbit",
    "peak_orbit_samples": "bsfs_jax.design._orbit",
    "point_hint": "bsfs_jax.design._orbit",
    "check_design_inputs": "bsfs_jax.design._sensitivity",
    "prefetch_programs": "bsfs_jax.design._sensitivity",
}

__all__ = list(_LAZY)

__getattr__, __dir__ = lazy_names(__name__, _LAZY)
