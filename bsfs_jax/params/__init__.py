"""Parameters: TOML <-> equinox Modules, validation, presets."""

from ._io import list_presets as list_presets
from ._io import load_params as load_params
from ._io import params_summary as params_summary
from ._io import params_to_toml as params_to_toml
from ._io import preset as preset
from ._io import preset_description as preset_description
from ._io import save_params as save_params
from ._params import BallScrewParams as BallScrewParams
from ._params import BearingParams as BearingParams
from ._params import Damping as Damping
from ._params import Masses as Masses
from ._params import NutParams as NutParams
from ._params import ParameterError as ParameterError
from ._params import ParameterWarning as ParameterWarning
from ._params import ScrewParams as ScrewParams
from ._params import ThermalParams as ThermalParams
from ._params import check_value as check_value
from ._params import lookup_key as lookup_key
from ._params import one_line as one_line
from ._params import validate as validate
from ._vocabulary import KEYS as KEYS
from ._vocabulary import PLAUSIBLE as PLAUSIBLE
