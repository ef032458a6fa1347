"""The forecast of an identified drive (`bsfs predict`).

`load_identified(folder)` / `identified_from_result(result)` -> `Identified`;
`forecast(identified, force_n=...)` -> the modal quantities (resonance [Hz], damping
ratio, stiffness), the FRC's peak and folds, the joints' lift-off forces [N] and a health
verdict per joint, each a `Quantity` with its 95 % interval (`forecast_modal`,
`forecast_liftoff`: parts of it); `ForecastError`. The forecast uses the rest of
identification; nothing there uses it.
"""

from ._forecast import forecast as forecast
from ._forecast import forecast_liftoff as forecast_liftoff
from ._forecast import forecast_modal as forecast_modal
from ._intervals import ForecastError as ForecastError
from ._intervals import Identified as Identified
from ._intervals import Quantity as Quantity
from ._intervals import identified_from_result as identified_from_result
from ._intervals import load_identified as load_identified
from ._result import Forecast as Forecast
