"""Parameter identification of the ball screw feed system from exciter records (issue 4).

Public API (the package uses only the public API of `bsfs_jax`):

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
  `forecast`, `Quantity`, `ForecastError`;
- bundled data: `bundled_records`, `DATA_DIR`.
"""

from ._choice import MODEL_ERROR as MODEL_ERROR
from ._csv import write_frf_csv as write_frf_csv
from ._csv import write_record_csv as write_record_csv
from ._fit import FitResult as FitResult
from ._fit import fit as fit
from ._forecast import ForecastError as ForecastError
from ._forecast import Identified as Identified
from ._forecast import Quantity as Quantity
from ._forecast import identified_from_result as identified_from_result
from ._forecast import load_identified as load_identified
from ._forecast_run import forecast as forecast
from ._forecast_run import forecast_liftoff as forecast_liftoff
from ._forecast_run import forecast_modal as forecast_modal
from ._frf import FrfRecord as FrfRecord
from ._frf import estimate_frf as estimate_frf
from ._frf import frf_variance as frf_variance
from ._lines import MAX_LINES as MAX_LINES
from ._lines import merge_lines as merge_lines
from ._load import load_record as load_record
from ._load import load_records as load_records
from ._measurement import HarmonicData as HarmonicData
from ._measurement import harmonic_analysis as harmonic_analysis
from ._parameters import DEFAULT_FIT as DEFAULT_FIT
from ._parameters import FIT_PARAMETERS as FIT_PARAMETERS
from ._parameters import PRELOAD_FIT as PRELOAD_FIT
from ._parameters import parse_fit as parse_fit
from ._parameters import parse_priors as parse_priors
from ._plan import PlannedRecord as PlannedRecord
from ._plan import TestPlan as TestPlan
from ._plan import candidate_plans as candidate_plans
from ._plan import fisher_std as fisher_std
from ._plan import fisher_stds as fisher_stds
from ._plan import plan_from_records as plan_from_records
from ._plan import plan_test as plan_test
from ._posterior import MIN_DRAWS as MIN_DRAWS
from ._posterior import Posterior as Posterior
from ._posterior import posterior as posterior
from ._posterior import posterior_text as posterior_text
from ._problem import Problem as Problem
from ._profile import profile_intervals as profile_intervals
from ._records import Record as Record
from ._records import RecordError as RecordError
from ._refits import REFITS as REFITS
from ._refits import Refits as Refits
from ._refits import refit as refit
from ._refits import refits_by_default as refits_by_default
from ._refits import refits_for as refits_for
from ._refits import save_refits as save_refits
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
from ._synth import TestEffects as TestEffects
from ._synth import synthesize as synthesize
from ._synth import synthesize_many as synthesize_many
from ._tdms import load_tdms as load_tdms
from ._tdms import write_record_tdms as write_record_tdms
from ._uff import write_frf_uff as write_frf_uff
from ._uff import write_record_uff as write_record_uff
from ._uncertainty import Uncertainty as Uncertainty
from ._uncertainty import uncertainty as uncertainty
