"""Condition monitoring over time: a drive's test history to a baseline, the change from
it, a trend with its prediction band, change points, the hours to a limit with a 95 %
interval, a status and an action per joint (numpy/scipy: small statistics, no JAX)."""

from ._history import History as History
from ._history import HistoryError as HistoryError
from ._history import Series as Series
from ._history import read_history_csv as read_history_csv
from ._history import read_manifest as read_manifest
from ._monitor import Level as Level
from ._monitor import MonitorResult as MonitorResult
from ._monitor import QuantityResult as QuantityResult
from ._monitor import TimeToLimit as TimeToLimit
from ._monitor import monitor as monitor
from ._monitor import monitor_quantity as monitor_quantity
from ._monitor import parse_level as parse_level
from ._passage import crossing_draws as crossing_draws
from ._report import monitor_figure as monitor_figure
from ._report import monitor_html as monitor_html
from ._report import write_monitor as write_monitor
from ._steps import change_points as change_points
from ._trends import Fit as Fit
from ._trends import fit_models as fit_models
