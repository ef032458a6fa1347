"""Figures from computed results (no computing here): each function returns a Figure."""

from ._analysis import plot_bifurcation as plot_bifurcation
from ._analysis import plot_frc as plot_frc
from ._analysis import plot_response as plot_response
from ._analysis import plot_waterfall as plot_waterfall
from ._atlas import plot_atlas_amplitude as plot_atlas_amplitude
from ._atlas import plot_atlas_motion as plot_atlas_motion
from ._compare import identification_comparison_figure as identification_comparison_figure
from ._continuation import plot_continuation as plot_continuation
from ._continuation import stability_segments as stability_segments
from ._design import optimization_summary as optimization_summary
from ._design import tornado as tornado
from ._forecast import forecast_figure as forecast_figure
from ._frf_fit import frf_fit_figure as frf_fit_figure
from ._identification import correlation_figure as correlation_figure
from ._identification import fit_figure as fit_figure
from ._identification import plan_figure as plan_figure
from ._response import response_figure as response_figure
from ._response import trajectory_spectrum as trajectory_spectrum
