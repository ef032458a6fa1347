"""Figures from computed results (no computing here): each function returns a Figure."""

from ._analysis import plot_bifurcation as plot_bifurcation
from ._analysis import plot_frc as plot_frc
from ._analysis import plot_response as plot_response
from ._analysis import plot_waterfall as plot_waterfall
