"""Period-n evidence for the verifier: orbit trials from sampled states, accepted only
with a converged residual, a minimal period, multipliers inside the unit circle and
samples that follow the orbit's linearisation (see `_verify.py`)."""

import warnings

import jax
import numpy as np

from .._numerics import half_range
from ..solvers import check_orbits, check_orbits_lanes, prefetch_check_orbits
from . import _evidence as ev
from ._classify import strobe_period

PERIODIC_PREFIX = "period-"
#: Kernel-check layouts that failed in this process (`OrbitTrials.kernel_key`).
_KERNEL_FAILED: set = set()


def scale_of(amplitude, y):
    """Per-coordinate scale of a point: max(|amplitude|, |y|), floored at 1e-3 of the
    largest (ones if all vanish)."""
    s = np.maximum(np.abs(np.asarray(amplitude, dtype=float)), np.abs(np.asarray(y)))
    peak = np.max(s) if s.size else 0.0
    return np.maximum(s, 1e-3 * peak if peak > 0 else 1.0)


class OrbitTrials:
    """Orbit trials of one problem under `VerifySettings`; `observe` is the coordinate
    whose amplitude is reported; `lanes`: points per lockstep batch of the checks (default
    `settings.batch`; a wide verification gives its chunk's, `VerifySettings.lanes_for`)."""

    def __init__(self, problem, settings, observe: int, lanes: int | None = None,
                 kernel: dict | None = None):
        self.p, self.s, self.obs = problem, settings, observe
        self.lanes = int(settings.batch if lanes is None else lanes)
        # {"fast", "block", "looped"}: the checks on the per-lane kernel (`check_orbits_lanes`, on
        # the problem's component field), else None (vmapped, `check_orbits`); not where
        # they failed before in this process (one warning, not one per chunk)
        self.kernel = kernel
        if kernel is not None and self.kernel_key() in _KERNEL_FAILED:
            self.kernel = None

    def kernel_key(self):
        """What a failure of the kernel checks is remembered by: the field, the lanes."""
        return id(self.p.component_field), self.lanes, tuple(sorted((self.kernel or {}).items()))

    def prefetch(self) -> None:
        """Start compiling the orbit checks' program in the background (a sweep asks for
        it before it integrates; `orbits` then finds it compiled)."""
        s = self.s
        if self.kernel is not None:
            return
        prefetch_check_orbits(self.p.vector_field, self.p.setup, self.p.data, self.lanes,
                              self.p.n_states, tol=s.orbit_tol, max_steps=s.orbit_max_steps,
                              max_period=s.max_period, settings=s.orbit_settings)

    def orbits(self, items, again: bool = True):
        """items: list of (value, y, scale, n) -> list of OrbitCheck rows (host)."""
        out = []
        s = self.s
        for k in range(0, len(items), self.lanes):
            part = items[k:k + self.lanes]
            # Always a full batch (the last item repeated): one shape, so one compiled
            # program for every call (a first sweep compiled it for 16, 8 and 1 items:
            # three programs of 5 s each, against a few lanes of repeated work).
            pad = part + [part[-1]] * (self.lanes - len(part))
            vals, ys, scs, ns = (np.array([it[j] for it in pad]) for j in range(4))
            if self.kernel is None:
                chk = check_orbits(self.p.vector_field, self.p.setup, self.p.data, vals, ys,
                                   scs, ns, tol=s.orbit_tol, max_steps=s.orbit_max_steps,
                                   max_period=s.max_period, settings=s.orbit_settings)
            else:
                try:
                    chk = check_orbits_lanes(self.p.component_field, self.p.setup,
                                             self.p.data, vals, ys, scs, ns, tol=s.orbit_tol,
                                             max_steps=s.orbit_max_steps,
                                             max_period=s.max_period,
                                             settings=s.orbit_settings, **self.kernel)
                    jax.block_until_ready(chk)  # a failure at run time falls back too
                except Exception as exc:  # noqa: BLE001 - the kernel's compiler refused it
                    warnings.warn(f"orbit checks on the kernel failed ({type(exc).__name__}: "
                                  f"{str(exc).splitlines()[0] if str(exc) else ''}); "
                                  "checking them vmapped instead", RuntimeWarning,
                                  stacklevel=2)
                    _KERNEL_FAILED.add(self.kernel_key())
                    self.kernel = None
                    return self.orbits(items, again)
            host = {f: np.asarray(getattr(chk, f)) for f in
                    ("state", "converged", "residual", "multipliers", "strobe", "samples",
                     "jac_distance", "monodromy")}
            out += [{f: a[j] for f, a in host.items()} for j in range(len(part))]
        # Multipliers from a matrix evaluated far from the orbit: evaluate them at it.
        far = [k for k, c in enumerate(out) if c["converged"] and
               c["jac_distance"] > s.jac_tol]
        if again and far:
            redo = self.orbits([(items[k][0], out[k]["state"], items[k][2], items[k][3])
                                for k in far], again=False)
            for k, c in zip(far, redo, strict=True):
                out[k] = c
        return out

    def accept(self, chk, n, strobe, scale, period):
        """A verdict dict if the orbit check `chk` (period n) verifies, else a reason."""
        if not chk["converged"]:
            return None, f"no period-{n} orbit from the sampled state (Newton residual " \
                         f"{chk['residual']:.2g})"
        mu = float(np.max(np.abs(chk["multipliers"])))
        if not mu < 1.0:
            return None, f"the period-{n} orbit found is unstable (max |mu| = {mu:.4f})"
        m = ev.minimal_period(chk["state"], chk["strobe"], n, scale, tol=self.s.separation_tol)
        if m < n:
            # Its points repeat after m periods within the separation tolerance: a period-m
            # orbit solved as n-periodic (its multipliers are those of period m, raised to
            # n / m). Only an m-period trial may label it.
            return None, (f"the period-{n} orbit found repeats after {m} period(s) (a "
                          f"period-{m} orbit solved over {n} periods)")
        pts = np.concatenate([chk["state"][None], chk["strobe"][:m - 1]], axis=0)
        dev, misfit = ev.linear_approach(strobe, pts, chk["monodromy"], scale,
                                         self.s.near_tol)
        if misfit > self.s.linear_tol:
            return None, (f"a stable period-{m} orbit exists, but the samples do not follow"
                          f" its linearisation (misfit {misfit:.2f}, deviation {dev:.2g})")
        x = chk["samples"][:, self.obs]
        amp = float(half_range(np.append(x[np.isfinite(x)], chk["state"][self.obs])))
        strobe_x = np.full(self.s.max_period, np.nan)
        strobe_x[:m] = pts[:, self.obs]
        return {"motion": f"{PERIODIC_PREFIX}{m}", "verified": True, "period_n": m,
                "orbit_strobe": strobe_x,
                "amplitude": amp, "orbit_residual": float(chk["residual"]),
                "max_multiplier": mu, "lyapunov_per_period": float(np.log(mu) / n),
                "lyapunov_low": float("nan"), "lyapunov_high": float("nan"),
                "reason": (f"stable period-{m} orbit: residual {chk['residual']:.1e}, "
                           f"max |mu| {mu:.4f}; the samples approach it along its "
                           f"linearisation (deviation {dev:.1e}, misfit {misfit:.2f})")}, None

    def try_orbits(self, entries):
        """entries: list of (key, value, strobe (k, d), amplitude (d,), period, extra_ns).
        Returns ({key: verdict} for the verified ones, {key: reason} for the others).
        First n = 1 and the extra periods; then, for the points left, the period of the
        samples' loose repetition. A wide verification (`VerifySettings.is_wide`) checks
        in the first call too the candidates no longer than its longest trial (n at most
        the largest extra period), n = 1 preferred: on an accelerator the lanes of a
        lockstep call are free, but their length is not (the call lasts as long as its
        longest lane's n periods, times its chord iterations), so a candidate period
        longer than the first call's waits for the points that n = 1 did not verify.
        Checking every candidate in the first call cost B1 (256 points, wide, on the CPU)
        110 lockstep periods (over the calls, the longest lane's n times its chord
        iterations + 2), with candidates of up to 8 periods beside n = 1, against 69
        with them apart, for the same 256 period-1 verdicts."""
        # candidate periods of the first call: 2..longest (none where narrow)
        longest = max((max(e[5], default=1) for e in entries), default=1) \
            if self.s.is_wide() else 1
        found, reasons = self._try(entries, first=True, candidates=(2, longest))
        rest = [e for e in entries if e[0] not in found]
        more, why = self._try(rest, first=False,
                              candidates=(longest + 1, self.s.max_period))
        found.update(more)
        for k, r in why.items():
            reasons.setdefault(k, r)
        return found, reasons

    def _try(self, entries, first: bool, candidates: tuple[int, int]):
        """One call of orbit trials: n = 1 and the extra periods (`first`), and the
        samples' candidate period where it lies in `candidates` (low, high)."""
        items, owners = [], []
        low, high = candidates
        for key, value, strobe, amp, period, extra in entries:
            y = strobe[-1]
            sc = scale_of(amp, y)
            ns = sorted({1, *extra}) if first else []
            if low <= high:  # the period of the samples' loose repetition
                cand = strobe_period(strobe, scale=sc, max_period=self.s.max_period,
                                     tol=self.s.candidate_tol)
                ns += [cand] if low <= cand <= high and cand not in extra else []
            for n in ns:
                items.append((value, y, sc, n))
                owners.append((key, n, strobe, sc, period))
        checks = self.orbits(items) if items else []
        found, reasons = {}, {}
        for (key, n, strobe, sc, period), chk in zip(owners, checks, strict=True):
            if key in found:
                continue
            v, why = self.accept(chk, n, strobe, sc, period)
            if v is not None:
                found[key] = v
            elif key not in reasons or n == 1:
                reasons[key] = why
        return found, reasons

    def settle(self, run, pending, values, periods, state, used):
        """Settle blocks (`VerifySettings.settle`): run the points `pending` on by
        `run(values, states)` (`_sweep_engines.SettleRuns`) up to `settle_blocks` times,
        trying their records for orbits after each. Updates `state` and `used` (time
        integrated) in place; returns ({key: verdict}, {key: reason}, {key: settle time})
        for the points verified, the reasons of the others, and every point's settle time."""
        found, reasons = {}, {}
        spent = dict.fromkeys(pending, 0.0)
        for _ in range(int(self.s.settle_blocks)):
            if not pending:
                break
            strobes, amps, ok = run(values[pending], np.array([state[k] for k in pending]))
            entries = []
            for j, k in enumerate(pending):
                if ok[j]:  # else left to the long runs, which report a failure
                    state[k] = strobes[j][-1]
                    used[k] += run.periods * periods[k]
                    spent[k] += run.periods * periods[k]
                    entries.append((k, values[k], strobes[j], amps[j], periods[k], ()))
            more, why = self.try_orbits(entries)
            for k, v in more.items():  # transient: the time before the evidence (the record)
                found[k] = {**v, "transient": used[k] - run.record_periods * periods[k]}
            reasons.update(why)
            # A point whose run failed goes straight to the long runs (the same state
            # would fail the same way again here).
            settled = {k for j, k in enumerate(pending) if ok[j]}
            pending = [k for k in pending if k not in found and k in settled]
        return found, reasons, spent
