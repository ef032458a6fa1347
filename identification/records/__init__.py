"""Records and their file formats: what an exciter test wrote, read and checked.

- `Record`: a time record (force on the worktable [N] and worktable acceleration
  [m/s^2], each (N,) sampled uniformly, `time` (N,) [s]) with its header `meta`;
  `RecordError`: a bad file, one line naming the file, the line or key and what to do.
- `FrfRecord`: an FRF, accelerance [(m/s^2)/N] complex (L,) at `frequency_hz` (L,) with
  the variance of each line's (Re, Im) (L, 2); `estimate_frf(record)` makes one from a
  chirp or random time record (H1, Welch), `frf_variance(accelerance, coherence,
  n_averages)` is the random error of each line (L, 2).
- Reading: `load_record(path)` by suffix (`.csv`, `.uff`/`.unv` UFF58, `.tdms` with the
  optional npTDMS), `load_records(paths)` after a memory check; `load_tdms(path)`.
- Writing: `write_record_csv`, `write_record_uff`, `write_record_tdms`, `write_frf_csv`,
  `write_frf_uff` (atomic writes).
- Long FRFs: `merge_lines(frf, k)` merges runs of k adjacent lines (inverse-variance
  weighted), `merge_factor(n_lines, max_lines)` the k that brings n_lines to at most
  `max_lines` (default `MAX_LINES`).
- A stated anti-alias filter: `antialias_cutoff_hz(meta)` [Hz] (None: none stated) and
  `antialias_response(meta, frequencies_hz)` its complex response (L,) (None: none to
  divide out).
"""

from ._antialias import cutoff_hz as antialias_cutoff_hz
from ._antialias import response as antialias_response
from ._csv import write_frf_csv as write_frf_csv
from ._csv import write_record_csv as write_record_csv
from ._frf import FrfRecord as FrfRecord
from ._frf import estimate_frf as estimate_frf
from ._frf import frf_variance as frf_variance
from ._lines import MAX_LINES as MAX_LINES
from ._lines import merge_factor as merge_factor
from ._lines import merge_lines as merge_lines
from ._load import load_record as load_record
from ._load import load_records as load_records
from ._records import Record as Record
from ._records import RecordError as RecordError
from ._tdms import load_tdms as load_tdms
from ._tdms import write_record_tdms as write_record_tdms
from ._uff import write_frf_uff as write_frf_uff
from ._uff import write_record_uff as write_record_uff

__all__ = ["FrfRecord", "MAX_LINES", "Record", "RecordError", "antialias_cutoff_hz",
           "antialias_response", "estimate_frf", "frf_variance", "load_record", "load_records",
           "load_tdms", "merge_factor", "merge_lines", "write_frf_csv", "write_frf_uff",
           "write_record_csv", "write_record_tdms", "write_record_uff"]
