"""Parameter identification of the ball screw feed system from exciter records.

One sub-package per job, each with its own public `__init__`: `records` (records and
their file formats), `measurement` (the measurement model: data, predictions, residuals),
`fitting` (the problem and the fit), `intervals` (uncertainty), `planning` (test
planning), `synthesis` (synthetic records), `report` (the end-to-end run and its report)
and, on top of them, `forecasting` (`bsfs predict`). The package uses only the public API
of `bsfs_jax`. Its public names, re-exported here:

- records: `load_record`, `load_records`, `write_record_csv`, `write_record_uff`, `Record`,
  `RecordError`;
- TDMS records (optional npTDMS, `pip install 'bsfs[tdms]'`): `load_tdms`,
  `write_record_tdms`;
- FRFs: `FrfRecord`, `estimate_frf` (from chirp/random records), `frf_variance`,
  `write_frf_csv`, `write_frf_uff`;
- synthetic data: `synthesize`, `synthesize_many` (one test, several seeds), `TestEffects`;
- measurement model: `harmonic_analysis`, `HarmonicData`;
- fitting: `FIT_PARAMETERS`, `DEFAULT_FIT`, `PRELOAD_FIT`, `MODEL_ERROR`, `parse_fit`,
  `parse_priors`, `Problem`, `fit`, `identify`, `IdentificationResult`, `measurement_data`;
- uncertainty: `uncertainty`, `Uncertainty`, `profile_intervals`, `posterior` (NUTS),
  `Posterior`, `posterior_text`, `refit` (randomised-maximum-likelihood refits), `Refits`,
  `REFITS`, `save_refits`, `refits_by_default`, `refits_for`;
- reports: `report_dict`, `parameter_rows`, `summary_text`, `preload_verdicts`,
  `write_identified`;
- test planning: `plan_test`, `candidate_plans`;
- forecast (`bsfs predict`): `load_identified`, `identified_from_result`, `Identified`,
  `forecast` -> `Forecast` (typed, `to_dict()`), `Quantity`, `ForecastError`;
- bundled data: `bundled_records`, `DATA_DIR`.
"""

from .fitting import DEFAULT_FIT as DEFAULT_FIT
from .fitting import FIT_PARAMETERS as FIT_PARAMETERS
from .fitting import PRELOAD_FIT as PRELOAD_FIT
from .fitting import FitResult as FitResult
from .fitting import Problem as Problem
from .fitting import fit as fit
from .fitting import parse_fit as parse_fit
from .fitting import parse_priors as parse_priors
from .forecasting import Forecast as Forecast
from .forecasting import ForecastError as ForecastError
from .forecasting import Identified as Identified
from .forecasting import Quantity as Quantity
from .forecasting import forecast as forecast
from .forecasting import forecast_liftoff as forecast_liftoff
from .forecasting import forecast_modal as forecast_modal
from .forecasting import identified_from_result as identified_from_result
from .forecasting import load_identified as load_identified
from .intervals import MIN_DRAWS as MIN_DRAWS
from .intervals import REFITS as REFITS
from .intervals import Posterior as Posterior
from .intervals import Refits as Refits
from .intervals import Uncertainty as Uncertainty
from .intervals import posterior as posterior
from .intervals import posterior_text as posterior_text
from .intervals import profile_intervals as profile_intervals
from .intervals import refit as refit
from .intervals import refits_by_default as refits_by_default
from .intervals import refits_for as refits_for
from .intervals import save_refits as save_refits
from .intervals import uncertainty as uncertainty
from .measurement import MODEL_ERROR as MODEL_ERROR
from .measurement import HarmonicData as HarmonicData
from .measurement import harmonic_analysis as harmonic_analysis
from .planning import PlannedRecord as PlannedRecord
from .planning import TestPlan as TestPlan
from .planning import candidate_plans as candidate_plans
from .planning import fisher_std as fisher_std
from .planning import fisher_stds as fisher_stds
from .planning import plan_from_records as plan_from_records
from .planning import plan_test as plan_test
from .records import MAX_LINES as MAX_LINES
from .records import FrfRecord as FrfRecord
from .records import Record as Record
from .records import RecordError as RecordError
from .records import estimate_frf as estimate_frf
from .records import frf_variance as frf_variance
from .records import load_record as load_record
from .records import load_records as load_records
from .records import load_tdms as load_tdms
from .records import merge_lines as merge_lines
from .records import write_frf_csv as write_frf_csv
from .records import write_frf_uff as write_frf_uff
from .records import write_record_csv as write_record_csv
from .records import write_record_tdms as write_record_tdms
from .records import write_record_uff as write_record_uff
from .report import DATA_DIR as DATA_DIR
from .report import IdentificationResult as IdentificationResult
from .report import bundled_records as bundled_records
from .report import identify as identify
from .report import measurement_data as measurement_data
from .report import parameter_rows as parameter_rows
from .report import preload_verdicts as preload_verdicts
from .report import report_dict as report_dict
from .report import summary_text as summary_text
from .report import write_identified as write_identified
from .synthesis import TestEffects as TestEffects
from .synthesis import synthesize as synthesize
from .synthesis import synthesize_many as synthesize_many
