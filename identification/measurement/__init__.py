"""The measurement model: records reduced to harmonic data, and the model's prediction of
those data at a parameter vector theta, with its noise-weighted residual.

One residual evaluation walks this package only: `residual(theta, data, structure)` builds
the system at theta (`params_at`), predicts each speed group's sine harmonics (the
linearised FRF, its first-order harmonic-balance correction or the periodic orbit) and FRF
lines, and weighs the differences by their noise. The fit calls it once per evaluation
(`residual_with_jacobian` inside its solve, `residual_and_jacobian` on the host).

Data side (numpy):

- `harmonic_analysis(record)` -> `HarmonicData`: force and acceleration harmonics k = 1..H
  [N, m/s^2] (H,) complex with their variances (H, 2), the refined frequency [Hz], the
  sensors' noise; `measurement_data(record)`: a sine record's `HarmonicData`, a chirp or
  random record's estimated FRF, an FRF as it is; `is_frf(datum)`.

Model side (traced; theta (p,): ln(value / prior) or value - prior [um] per parameter):

- the data as arrays of a fixed layout: `FitData` (traced), `Structure` (static),
  `build_data(problem, is_frf)` -> (FitData, Structure, layout), `masked_orbit_records`,
  `used_rows` (m,) bool, `padded_counts`, `sine_variance` (H, 2), `sweep_direction`;
- the model: `params_at(theta, data, structure, group)`, `predict` and its compiled
  `predictions` (per speed group: sine harmonics (R, H), FRF accelerance (L,), drift
  terms (R, H), complex [m/s^2]), `residual` (m + p,), `residual_with_jacobian` (the same,
  its forward-mode Jacobian computed once), `residual_and_jacobian` (compiled: (m + p,),
  (m + p, p)), `traced_residual_and_jacobian`, `static_compliance` [m/N],
  `compliance_and_gradient` ((G,), (G, p));
- the linearised model: `receptance(system, f)` (L, 3) [m/N], `linear_acceleration`
  [m/s^2], `linearisation_error` (the first-order correction) [m/s^2];
- which model each record gets: `MODEL_ERROR`, `FRF_LINE_ERROR` [standard errors],
  `line_bound`, `screen`, `keep_marginal`, `same_choice`, `error_in_std`;
- periodic orbits: `ORBIT_HARMONICS`, `branches` (which branch a record is on, at the
  estimate), `prefetch_branches`, `swept_state` (a stepped sine's orbit, for synthetic
  records); swept records' anchors: `anchored`, `settle`, `MAX_ANCHOR_ROUNDS`;
- the orbit records' weights through the model's force derivatives: `force_gains`;
- `require_x64(what)`: refuse to run in 32-bit floats.
"""

from ._anchors import MAX_ROUNDS as MAX_ROUNDS
from ._anchors import anchored as anchored
from ._anchors import settle as settle
from ._choice import FRF_LINE_ERROR as FRF_LINE_ERROR
from ._choice import MODEL_ERROR as MODEL_ERROR
from ._choice import error_in_std as error_in_std
from ._choice import keep_marginal as keep_marginal
from ._choice import line_bound as line_bound
from ._choice import same_choice as same_choice
from ._choice import screen as screen
from ._force_noise import force_gains as force_gains
from ._groups import FitData as FitData
from ._groups import GroupData as GroupData
from ._groups import Structure as Structure
from ._groups import build_data as build_data
from ._groups import masked_orbit_records as masked_orbit_records
from ._groups import padded_counts as padded_counts
from ._groups import sine_variance as sine_variance
from ._groups import sweep_direction as sweep_direction
from ._groups import used_rows as used_rows
from ._harmonics import HarmonicData as HarmonicData
from ._harmonics import harmonic_analysis as harmonic_analysis
from ._harmonics import is_frf as is_frf
from ._harmonics import measurement_data as measurement_data
from ._linear import linear_acceleration as linear_acceleration
from ._linear import linearisation_error as linearisation_error
from ._linear import receptance as receptance
from ._model import compliance_and_gradient as compliance_and_gradient
from ._model import params_at as params_at
from ._model import predict as predict
from ._model import predictions as predictions
from ._model import residual as residual
from ._model import residual_and_jacobian as residual_and_jacobian
from ._model import residual_with_jacobian as residual_with_jacobian
from ._model import static_compliance as static_compliance
from ._model import traced_residual_and_jacobian as traced_residual_and_jacobian
from ._orbit_model import ORBIT_HARMONICS as ORBIT_HARMONICS
from ._orbit_model import branches as branches
from ._orbit_model import prefetch_branches as prefetch_branches
from ._orbit_model import swept_state as swept_state
from ._precision import require_x64 as require_x64

MAX_ANCHOR_ROUNDS = MAX_ROUNDS  # the anchors' most rounds (its name in the fit)
