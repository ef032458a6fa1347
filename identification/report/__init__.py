"""The end-to-end identification run and what it reports.

`identify(paths or records, fit=..., ...)` -> `IdentificationResult` (records read, model
chosen, fitted, intervals, profile check); `report_dict` (report.json),
`write_identified` (identified.toml), `parameter_rows`, `summary_text`,
`preload_verdicts` (preload loss or increase, with its evidence); `measurement_data`;
the bundled synthetic data sets: `bundled_records(name)`, `DATA_DIR`.
"""

from ._report import DATA_DIR as DATA_DIR
from ._report import IdentificationResult as IdentificationResult
from ._report import bundled_records as bundled_records
from ._report import identify as identify
from ._report import measurement_data as measurement_data
from ._report import report_dict as report_dict
from ._report import write_identified as write_identified
from ._summary import parameter_rows as parameter_rows
from ._summary import preload_verdicts as preload_verdicts
from ._summary import summary_text as summary_text
