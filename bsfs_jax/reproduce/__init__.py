"""Reproduction of the paper's Section 3 (Figs. 10-27) and its claims table.

- `reproduce(out_dir, settings)`: compute, save the figures and write REPRODUCTION.md;
- `ReproduceSettings` (`ReproduceSettings.quick_settings()` for a one-minute run);
- `CLAIMS`: the rows of physics.md section 6; `FIGURE_FILES`: the figure file names.
"""

from ._claims import CLAIM_KEYS as CLAIM_KEYS
from ._claims import CLAIMS as CLAIMS
from ._claims import Claim as Claim
from ._report import FIGURE_FILES as FIGURE_FILES
from ._report import reproduce as reproduce
from ._run import ReproduceSettings as ReproduceSettings
from ._run import Reproduction as Reproduction
