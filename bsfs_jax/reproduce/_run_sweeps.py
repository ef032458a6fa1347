"""The frequency sweeps of Figs. 24-27, their cache and the verification of cached sweeps.

Every sweep uses one `SweepConfig` and one number of points, so the continued-sweep kernel
is compiled once (see `_run.py`). Finished sweeps are saved under the report's `sweeps/`
folder with a key of their parameters and settings, so the report can be regenerated
without recomputing them.
"""

import hashlib
import json
from pathlib import Path

import numpy as np

from .._files import jsonable
from ..analysis import SweepConfig, bsfs_problem, load_sweep, sweep, verify_sweep
from ._run import SWEEP_VARIANTS, ReproduceSettings, _system_and_modes

#: The sweeps whose motion labels are verified (the bifurcation diagrams' claims).
VERIFIED_SWEEPS = ("fig24", "fig25")


def sweep_experiments(params, s: ReproduceSettings, progress: bool = False,
                      cache_dir=None) -> dict:
    """Figs. 24-27: continued up/down frequency sweeps of each variant (one compile).

    The sweeps of `VERIFIED_SWEEPS` (Figs. 24-25) also get verified labels
    (`verify_sweep`, `res.verdicts`); Figs. 26-27 are about amplitudes and jumps only.
    With `cache_dir`, each finished sweep is saved there (`SweepResult.save`, verdicts
    included) with a key of its parameters and settings; a later run with the same key
    loads it instead of recomputing (so the report can be regenerated cheaply), and a
    cached sweep without verdicts (or with other verifier settings) is only verified.
    """
    freqs = np.linspace(s.sweep_start_hz, s.sweep_stop_hz, s.sweep_points)
    cfg = SweepConfig(transient_periods=s.sweep_transient,
                      continued_transient_periods=s.sweep_continued_transient,
                      periods=s.sweep_periods, samples_per_period=s.sweep_samples_per_period,
                      lyapunov=True,
                      lyapunov_align_periods=min(16, s.sweep_continued_transient // 2),
                      batch_size=0, chunk_size=s.sweep_points,
                      settings=s.solver_settings())
    cache, out = {}, {}
    for fig, name, values, label, unit in SWEEP_VARIANTS:
        results = {}
        verify = fig in VERIFIED_SWEEPS
        for v in values:
            p = params.replace(name, v)
            key = _sweep_key(p, freqs, s)
            path = None if cache_dir is None else Path(cache_dir) / f"{name}={v:g}.nc"
            if key not in cache:
                cache[key] = _cached_sweep(p, freqs, cfg, s, key, progress, path, verify)
            elif verify and not _has_verdicts(cache[key], s):
                cache[key] = _verify_cached(p, cache[key], s, progress, path)
            results[v] = cache[key]
        mode_hz = {v: float(np.asarray(_system_and_modes(params.replace(name, v))[1])[0])
                   for v in values}
        out[fig] = {"param": name, "label": label, "unit": unit, "results": results,
                    "mode_hz": mode_hz}
    return out


def _sweep_key(params, freqs, s: ReproduceSettings) -> str:
    h = hashlib.sha256()
    for leaf in _leaves(params):
        h.update(np.ascontiguousarray(np.asarray(leaf, dtype=float)).tobytes())
    h.update(np.ascontiguousarray(freqs).tobytes())
    fields = ("force_n", "sweep_transient", "sweep_continued_transient", "sweep_periods",
              "sweep_samples_per_period", "rtol", "atol", "solver")
    h.update(repr([getattr(s, f) for f in fields]).encode())
    return h.hexdigest()[:24]


def _verify_tag(s: ReproduceSettings) -> str:
    return json.dumps(jsonable(s.verify_settings().to_dict()), sort_keys=True)


def _has_verdicts(res, s: ReproduceSettings) -> bool:
    return res.verdicts is not None and res.metadata.get("reproduce_verify") == _verify_tag(s)


def _verify_cached(params, res, s: ReproduceSettings, progress, path):
    """Verify every point of a continued sweep (each point ran the continued transient)
    and save it again."""
    problem = bsfs_problem(params, force_n=s.force_n)
    n_tr = np.full(res.values.size, s.sweep_continued_transient)
    res.verdicts = verify_sweep(problem, res, settings=s.verify_settings(), transient=n_tr,
                                progress=progress)
    res.metadata["reproduce_verify"] = _verify_tag(s)
    res.metadata["verify_settings"] = jsonable(s.verify_settings().to_dict())
    if path is not None:
        res.save(path)
    return res


def _cached_sweep(params, freqs, cfg, s, key, progress, path, verify: bool = False):
    res = None
    if path is not None and path.exists():
        try:
            res = load_sweep(path)
            if res.metadata.get("reproduce_key") == key:
                res.metadata["loaded_from_cache"] = True
            else:
                res = None
        except (OSError, ValueError, KeyError):
            res = None  # unreadable or stale: recompute
    if res is None:
        res = sweep(bsfs_problem(params, force_n=s.force_n), freqs, mode="continued",
                    direction="both", config=cfg, progress=progress,
                    metadata={"reproduce_key": key})
        if path is not None:
            res.save(path)
    if verify and not _has_verdicts(res, s):
        res = _verify_cached(params, res, s, progress, path)
    return res


def _leaves(params):
    import jax

    return jax.tree_util.tree_leaves(params)
