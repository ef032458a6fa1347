"""What counts as information in a noise-weighted Jacobian, and the remaining-step test.

Host-side (numpy) helpers shared by the fit's evidence (`_fit.py`), the uncertainty and the
profile likelihood; the solve itself is `_solve.py` (optimistix), whose in-loop stopping
test (`_solve.gn_step`) is the traced twin of `gn_step_sigma`.
"""

from __future__ import annotations

import numpy as np

#: Without priors (maximum likelihood), a direction whose standard error exceeds this (in
#: log-value, i.e. a factor e, or um) carries no usable information: over one standard
#: error the model is far from linear, the optimiser's steps there are meaningless, and its
#: parameters are reported as not determined. (With priors every direction is informative:
#: the prior bounds its standard error.) Singular values below 1e-10 x the largest are
#: round-off in any case.
NO_INFORMATION_STD = 1.0
NULL_RTOL = 1e-10


def informative(s, max_std: float | None = None) -> np.ndarray:
    """Which singular values (descending, of a noise-weighted Jacobian) carry information."""
    s = np.asarray(s, float)
    if not s.size or not s[0] > 0:
        return np.zeros(s.shape, bool)
    floor = 0.0 if max_std is None else 1.0 / max_std
    return s > max(s[0] * NULL_RTOL, floor)


def gn_step_sigma(r, j, max_std: float | None = None) -> float:
    """Largest remaining Gauss-Newton step component / its standard error (SVD of J), over
    the informative directions."""
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(j))):
        return float("inf")
    u, s, _ = np.linalg.svd(j, full_matrices=False)
    keep = informative(s, max_std)
    if not np.any(keep):
        return float("inf")
    return float(np.max(np.abs(u[:, keep].T @ r)))
