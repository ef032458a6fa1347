"""Writing files: the one public home (`bsfs_jax._files` holds the code).

Every output of the package and of the packages built on it (identification's records and
reports, sweeps, atlases, figures) is written through these, so a reader never sees a
half-written file and an interrupted write leaves the old file intact.
"""

from ._files import jsonable as jsonable
from ._files import save_figure as save_figure
from ._files import save_netcdf_atomic as save_netcdf_atomic
from ._files import save_npz_atomic as save_npz_atomic
from ._files import write_atomic as write_atomic
from ._files import write_bytes_atomic as write_bytes_atomic
from ._files import write_text_atomic as write_text_atomic
