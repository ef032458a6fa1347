"""Verified steady states: a motion label only with its evidence, else "unresolved".

A sweep samples each point's response after a transient; the samples alone cannot tell a
periodic orbit still shedding a lightly damped mode from a torus or period-n motion. Here
every label needs evidence (generic over any forced field, used on textbook systems and
the ball screw alike):

- **period-n**: Newton's method on Phi^{nT}(y) = y from the sampled state converges
  (scaled residual below `orbit_tol`), n is minimal, every Floquet multiplier lies inside
  the unit circle, and the sampled trajectory approaches the orbit (its stroboscopic
  distance to the orbit falls, or is already within `near_tol`). Candidates: n = 1 and
  the period of the samples' loose repetition.
- **quasi-periodic**: after the trajectory stopped drifting, the largest Lyapunov exponent
  per forcing period is zero within its 95 % confidence interval (independent segments),
  the rotation number of the stroboscopic points is not locked to p/q (q <= max_period),
  the points lie on one smooth closed curve, and no stable orbit of period <= max_period
  is found from the sampled state.
- **chaotic**: lambda T > 0 with a confidence interval that excludes 0, and a broadband
  spectrum (power fraction in the strongest lines below `line_fraction_min`).

Points that satisfy none are "unresolved", with the reason. Points with no orbit from
the sweep's samples are continued in blocks (`block_periods`), with the engine tried
again after each block (it jumps to an orbit rather than waiting for the decay), until a
verdict or the budget (`budget_time_constants` / slowest linear decay rate).
"""

import functools
import hashlib
import json
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._files import jsonable, save_npz_atomic
from .._numerics import half_range
from ..solvers import host_eigvals, result_codes, result_text
from . import _evidence as ev
from ._block_verdict import UNRESOLVED, block_verdict
from ._extend import run_block
from ._lyapunov import initial_tangent
from ._orbit_trials import OrbitTrials
from ._verify_settings import FAILED, VERDICT_FIELDS, VerifySettings


@eqx.filter_jit
def _decay_rates(problem, values):
    def one(v):
        args, _ = problem.setup(problem.data, v)
        jac = jax.jacfwd(lambda y: problem.vector_field(0.0, y, args))(problem.y0)
        rate = -jnp.real(host_eigvals(jac))
        return jnp.where(jnp.all(rate > 0), jnp.min(rate), jnp.nan)

    return jax.vmap(one)(values)


#: `slowest_decay_rate` evaluates its values in chunks of this many (the last one padded):
#: one program for any count (a sweep asks for all its values, then for the few that need
#: long runs; each count compiled a program of its own, 0.4-0.5 s cold).
_DECAY_CHUNK = 64


def slowest_decay_rate(problem, values) -> np.ndarray:
    """Slowest decay rate min(-Re lambda) [1/time unit] of the linearisation at
    `problem.y0` for each value (NaN where some eigenvalue does not decay)."""
    flat = np.asarray(values, dtype=float).reshape(-1)
    if flat.size == 0:
        return np.zeros(np.shape(values))
    padded = np.concatenate([flat, np.full(-flat.size % _DECAY_CHUNK, flat[-1])])
    rates = [np.asarray(_decay_rates(problem, jnp.asarray(padded[i:i + _DECAY_CHUNK],
                                                          dtype=float)))
             for i in range(0, padded.size, _DECAY_CHUNK)]
    return np.concatenate(rates)[:flat.size].reshape(np.shape(values))


def minimum_transient(problem, values, periods, settings: VerifySettings = VerifySettings(),
                      fallback: int = 200) -> np.ndarray:
    """Transient periods per value: `decay_folds` slowest-mode time constants, at least
    `min_transient_periods`; `fallback` periods where no decay rate is known."""
    sigma = slowest_decay_rate(problem, values)
    per = np.asarray(periods, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        n = np.ceil(settings.decay_folds / (sigma * per))
    n = np.where(np.isfinite(n), n, fallback)
    return np.maximum(n, settings.min_transient_periods).astype(int)


#: Beside the (D, N) fields: the verified orbit's observed coordinate at t = k T,
#: k = 0..n-1 (NaN beyond n and where no orbit was verified), shape (D, N, max_period).
ORBIT_STROBE = "orbit_strobe"


def _empty(shape, max_period: int):
    out = {name: np.full(shape, np.nan) for name in VERDICT_FIELDS}
    out[ORBIT_STROBE] = np.full(tuple(shape) + (int(max_period),), np.nan)
    out["motion"] = np.full(shape, UNRESOLVED, dtype=object)
    out["reason"] = np.full(shape, "", dtype=object)
    out["verified"] = np.zeros(shape, dtype=bool)
    out["period_n"] = np.zeros(shape, dtype=int)
    return out


def verify_points(problem, values, strobes, amplitudes, periods, transients, *,
                  settings: VerifySettings = VerifySettings(), progress: bool = False,
                  lanes: int | None = None, settle=None, kernel: dict | None = None):
    """Verify K sampled points: `strobes` (K, k, d) stroboscopic samples ending at the
    state to continue from; `amplitudes` (K, d); `periods` (K,); `transients` (K,) time
    already integrated. Returns a dict of (K,) verdict arrays (`VERDICT_FIELDS`).
    `lanes`: lockstep lanes of the checks (default `settings.lanes_for(K)`); a wide
    verification also pads its continuation blocks to that many points. `settle`: the
    settle blocks' runner (`_sweep_engines.SettleRuns`), or None for none. `kernel`:
    {"fast", "block", "looped"} to run the orbit checks on the per-lane kernel
    (`solvers.check_orbits_lanes`), or None (vmapped)."""
    s = settings
    K = len(values)
    out = _empty((K,), s.max_period)
    obs = problem.observe
    lanes = s.lanes_for(K) if lanes is None else int(lanes)
    ver = OrbitTrials(problem, s, obs, lanes=lanes, kernel=kernel)
    pad_to = lanes if s.is_wide() else 0
    entries = [(k, values[k], strobes[k], amplitudes[k], periods[k], ()) for k in range(K)]
    found, reasons = ver.try_orbits(entries)
    for k, v in found.items():
        for f, x in v.items():
            out[f][k] = x
        out["transient"][k] = transients[k]
    pending = [k for k in range(K) if k not in found]
    sigma = slowest_decay_rate(problem, values[pending]) if pending else np.array([])
    budget = {k: max(s.budget_time_constants / sig if np.isfinite(sig) else 0.0,
                     s.min_blocks * s.block_periods * periods[k])
              for k, sig in zip(pending, sigma, strict=True)}
    state = {k: strobes[k][-1] for k in pending}
    tangent = {k: np.asarray(initial_tangent(problem.n_states)) for k in pending}
    used = {k: float(transients[k]) for k in pending}
    # Time of the settle blocks: not charged to the long runs' budget.
    settled = dict.fromkeys(pending, 0.0)
    if settle is not None and pending:
        found, why, settled = ver.settle(settle, pending, values, periods, state, used)
        for k, v in found.items():
            for f, x in v.items():
                out[f][k] = x
        reasons.update(why)
        pending = [k for k in pending if k not in found]
    last = {}
    from tqdm.auto import tqdm

    bar = tqdm(total=len(pending), unit="pt", disable=not progress or not pending,
               desc="verify (long runs)")
    for b in range(s.max_blocks):
        pending = [k for k in pending if used[k] - settled[k] - transients[k] < budget[k]]
        if not pending:
            break
        blk = run_block(problem, values[pending], np.array([state[k] for k in pending]),
                        np.array([tangent[k] for k in pending]), periods=s.block_periods,
                        samples_per_period=s.block_samples, settings=s.run_settings,
                        pad_to=pad_to)
        entries, stats = [], {}
        for j, k in enumerate(pending):
            if blk.status[j] != 0:
                out["motion"][k], out["reason"][k] = FAILED, "integration failed while " \
                    "continuing the run"
                continue
            strobe = blk.samples[j, :, -1, :]
            strobe = np.concatenate([state[k][None], strobe], axis=0)
            state[k], tangent[k] = blk.state[j], blk.tangent[j]
            used[k] += s.block_periods * periods[k]
            x = blk.samples[j].reshape(-1, problem.n_states)
            amp = half_range(x, axis=0)
            logs = blk.log_growth[j][s.align_periods if b == 0 else 0:]
            stats[k] = (strobe, amp, logs, x[:, obs])
            entries.append((k, values[k], strobe, amp, periods[k], ()))
        found, why = ver.try_orbits(entries)
        done = set()
        for k, v in found.items():
            for f, x in v.items():
                out[f][k] = x
            out["transient"][k] = used[k] - s.block_periods * periods[k]
            done.add(k)
        for k, (strobe, amp, logs, sig) in stats.items():
            if k in done:
                continue
            # The latest exponent estimate stays as evidence even without a verdict.
            lam = ev.exponent_interval(logs, s.segments)
            verdict = block_verdict(ver, k, values[k], strobe, amp, lam, sig, periods[k],
                             last.get(k), s)
            last[k] = (strobe, amp, logs)
            for f, x in zip(("lyapunov_per_period", "lyapunov_low", "lyapunov_high"), lam,
                            strict=True):
                out[f][k] = x
            if verdict is not None:
                for f, x in verdict.items():
                    out[f][k] = x
                out["transient"][k] = used[k] - s.block_periods * periods[k]
                done.add(k)
            else:
                reasons[k] = why.get(k, reasons.get(k, ""))
                out["amplitude"][k] = amp[obs]
        failed = {k for k in pending if out["motion"][k] == FAILED}
        bar.update(len(done | failed))
        pending = [k for k in pending if k not in done and k not in failed]
    bar.close()
    for k in range(K):
        if out["motion"][k] == UNRESOLVED and not out["reason"][k]:
            spent = used.get(k, transients[k]) - transients[k]
            out["reason"][k] = (f"no verdict within the budget ({spent:.3g} time units of "
                                f"continued integration); last: {reasons.get(k, '')}")
            out["transient"][k] = used.get(k, transients[k])
    return out


def verify_sweep(problem, result, *, settings: VerifySettings = VerifySettings(),
                 transient=None, progress: bool = False, checkpoint_dir=None,
                 chunk: int = 64, settle=None, kernel: dict | None = None, runner=None,
                 failures: list | None = None) -> dict:
    """Verdicts (dict of (D, N) arrays, `VERDICT_FIELDS`, and the (D, N, max_period)
    `orbit_strobe`) for every point of a sweep.

    `transient` (N,) periods integrated before the record (default the sweep's config).
    `settle`, `kernel`: the settle blocks' runner and the kernel checks (`verify_points`).
    With `checkpoint_dir`, the verdicts of each `chunk` of points are saved there as they
    are found (tagged with the settings and the sweep's fingerprint), so an interrupted
    verification resumes with the chunks not yet done. `runner`: verify the chunks not
    yet saved elsewhere (`sweep`'s `runner`); a chunk that failed on every attempt leaves
    its points unresolved with the cause, recorded in `failures` (a list) when given.
    """
    D, N = result.strobe.shape[:2]
    out = _empty((D, N), settings.max_period)
    codes = result_codes(result.result)
    texts = result_text(result.result)
    n_tr = (np.full(N, result.config.get("transient_periods", 0)) if transient is None
            else np.asarray(transient))
    P = result.strobe.shape[2] - 1
    keys = [(d, i) for d in range(D) for i in range(N) if codes[d, i] == 0]
    for d in range(D):
        for i in range(N):
            if codes[d, i] != 0:
                out["motion"][d, i] = FAILED
                out["reason"][d, i] = f"the sweep's integration failed: {texts[d, i]}"
    # The settings as resolved here (wide on this backend, settle blocks and kernel
    # checks as given), so verdicts of another resolution are not reused.
    resolved = dict(settings.to_dict(), wide=settings.is_wide(), settle=settle is not None,
                    kernel_checks=kernel is not None)
    # (the points verified, too: a rerun after a lost chunk of the sweep has more of them)
    tag = json.dumps([jsonable(resolved), result.metadata.get("fingerprint"),
                      np.asarray(n_tr).tolist(), hashlib.sha256(
                          np.asarray(keys, dtype=np.int64).tobytes()).hexdigest()[:16]],
                     sort_keys=True)
    folder = None if checkpoint_dir is None else Path(checkpoint_dir)
    from tqdm.auto import tqdm

    bar = tqdm(total=len(keys), unit="pt", disable=not progress or not keys, desc="verify")
    lanes = settings.lanes_for(min(int(chunk), len(keys)))
    parts = [keys[lo:lo + int(chunk)] for lo in range(0, len(keys), int(chunk))]
    paths = [None if folder is None else folder / f"verdicts_{c:05d}.npz"
             for c in range(len(parts))]

    def inputs(part):
        return (np.array([result.values[i] for _, i in part]),
                np.array([result.strobe[d, i] for d, i in part]),
                np.array([result.amplitude[d, i] for d, i in part]),
                np.array([result.period[i] for _, i in part]),
                np.array([(n_tr[i] + P) * result.period[i] for _, i in part]))

    def save(c, got):
        if paths[c] is not None and jax.process_index() == 0:
            save_npz_atomic(paths[c], tag=np.array(tag), **{f"v_{k}": a for k, a in got.items()})

    spec = (problem, settings, lanes, settle, kernel)
    found = {c: _load_chunk(paths[c], tag) for c in range(len(parts))}
    todo = {}
    if runner is not None:  # (the bar advances as they come back)
        from ._remote import run_elsewhere

        todo = {c: inputs(parts[c]) for c in found if found[c] is None}
        found.update(run_elsewhere(runner, functools.partial(_verify_part, spec), todo, save,
                                   bar, {c: len(parts[c]) for c in todo}))
    for c, part in enumerate(parts):
        got = found[c]
        if isinstance(got, BaseException):
            from ._remote import cause_of, failure

            if failures is not None:
                failures.append(failure("verification", c, inputs(part)[0], got))
            for d, i in part:
                out["reason"][d, i] = f"not verified: its chunk failed ({cause_of(got)})"
            continue
        if got is None:
            got = _verify_part(spec, inputs(part))
            save(c, got)
        if c not in todo:
            bar.update(len(part))
        for j, (d, i) in enumerate(part):
            for f in (*VERDICT_FIELDS, ORBIT_STROBE):
                if f in got:  # (chunks saved before orbit_strobe existed lack it)
                    out[f][d, i] = got[f][j]
    bar.close()
    out["motion"] = out["motion"].astype(str)
    out["reason"] = out["reason"].astype(str)
    return out


def _verify_part(spec, inputs) -> dict:
    """The verdicts of one chunk of points (`verify_sweep`), as saved: here, or elsewhere
    by a `runner` (the same function, so the same verdicts)."""
    problem, settings, lanes, settle, kernel = spec
    got = verify_points(problem, *inputs, settings=settings, lanes=lanes, settle=settle,
                        kernel=kernel)
    return {f: np.asarray(a).astype(str) if f in ("motion", "reason") else np.asarray(a)
            for f, a in got.items()}


def _load_chunk(path, tag):
    """A saved chunk of verdicts with this tag, or None (missing, other, damaged)."""
    if path is None or not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["tag"]) != tag:
                return None
            return {k[2:]: z[k] for k in z.files if k.startswith("v_")}
    except (OSError, ValueError, KeyError, EOFError):
        return None
