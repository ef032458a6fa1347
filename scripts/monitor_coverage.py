"""Do the monitor's intervals and step tests mean what they say? Synthetic histories.

Each history is one quantity (a preload, 1000 N new) tested every ~200 h, 10-40 tests,
each test with a known standard error (10 N, given to the monitor) plus an unknown
between-test scatter (5 N). The degradation is linear, exponential or a Wiener process
with drift, in equal shares; half the histories have a step (a repair restoring the
preload) at a random test with at least 3 tests on each side. The limit is 600 N; the
true crossing is the noise-free trend's (linear, exponential) or the latent path's first
passage (Wiener), 1.1-2 x the last test's hours after the last step.

    python scripts/monitor_coverage.py --histories 600 --out out/monitor_coverage

Writes OUT/rows.jsonl (one row per history, as it goes) and OUT/summary.md, .json.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from bsfs_jax.monitoring import Level, Series, monitor_quantity

Y0, LIMIT, STD, SCATTER, EVERY = 1000.0, 600.0, 10.0, 5.0, 200.0
KINDS = ("linear", "exponential", "wiener")


def _path(kind, rng, t, start_t, start_y, cross_t, sigma, end=None):
    """The latent level at hours t (array) from (start_t, start_y), reaching LIMIT at
    cross_t in mean; for a Wiener process also its first passage (on a 1 h grid).
    `end = (hours, level)`: a Wiener path pinned there (a Brownian bridge: the level
    just before a repair, so the repair restores what the study says)."""
    tau = t - start_t
    if kind == "linear":
        return start_y - (start_y - LIMIT) * tau / (cross_t - start_t), cross_t
    if kind == "exponential":
        lam = np.log(start_y / LIMIT) / (cross_t - start_t)
        return start_y * np.exp(-lam * tau), cross_t
    mu = (start_y - LIMIT) / (cross_t - start_t)
    horizon = start_t + 20 * (cross_t - start_t) if end is None else end[0]
    grid = np.arange(start_t, horizon + 1.0, 1.0)
    steps = -mu + sigma * rng.standard_normal(len(grid) - 1)
    x = start_y + np.concatenate([[0.0], np.cumsum(steps)])
    if end is not None:
        at = np.interp(end[0], grid, x)
        x = x - (grid - start_t) / (end[0] - start_t) * (at - end[1])
    below = np.nonzero(x <= LIMIT)[0]
    passage = float(grid[below[0]]) if below.size else np.inf
    return np.interp(t, grid, x), passage


def history(i: int, seed: int):
    """(hours, observed values, truth dict) of history i."""
    rng = np.random.default_rng([seed, i])
    kind = KINDS[(i // 2) % 3]
    step = i % 2 == 1
    while True:
        n = int(rng.integers(10, 41))
        hours = np.cumsum(EVERY * rng.uniform(0.9, 1.1, n))
        hours = hours - hours[0]
        k = int(rng.integers(3, n - 2)) if step else 0  # first test after the step
        sigma = rng.uniform(1.0, 3.0) * STD / np.sqrt(EVERY)  # Wiener, per sqrt(h)
        start_t = 0.5 * (hours[k - 1] + hours[k]) if step else 0.0
        span = hours[-1] - start_t
        cross = start_t + span * rng.uniform(1.1, 2.0) + (EVERY if span < EVERY else 0.0)
        x = np.empty(n)
        if step:  # before: degradation from new to 70-90 % (same kind), then a repair
            pre_end = Y0 * rng.uniform(0.7, 0.9)
            pre_cross = start_t * (Y0 - LIMIT) / (Y0 - pre_end)
            x[:k], _ = _path(kind, rng, hours[:k], 0.0, Y0, pre_cross, sigma,
                             end=(start_t, pre_end))
        x[k:], true_t = _path(kind, rng, hours[k:], start_t, Y0, cross, sigma)
        if np.isfinite(true_t) and true_t <= hours[-1] or np.min(x) <= LIMIT:
            continue  # crossed already before the last test: draw again
        break
    y = x + rng.normal(0, STD, n) + rng.normal(0, SCATTER, n)
    return hours, y, dict(kind=kind, step=step, step_index=k if step else None,
                          true_crossing_h=true_t, tests=n)


def run_one(i: int, seed: int) -> dict:
    hours, y, truth = history(i, seed)
    q = monitor_quantity(hours, Series("preload", "N", y, np.full(len(y), STD)),
                         limit=Level(value=LIMIT))
    idx = [int(np.searchsorted(hours, c)) for c in q.change_points_h]
    ttl = q.time_to_limit_h
    true_t = truth["true_crossing_h"]
    covered = None if ttl is None else bool(ttl.lower <= true_t <= ttl.upper)
    row = dict(history=i, **truth, model=q.model, change_point_index=idx,
               lower=None if ttl is None else ttl.lower,
               upper=None if ttl is None else ttl.upper,
               estimate=None if ttl is None else ttl.estimate, covered=covered)
    if truth["step"]:
        row["step_found"] = any(abs(j - truth["step_index"]) <= 1 for j in idx)
    else:
        row["false_step"] = bool(idx)
    return row


def _pct(xs):
    xs = [bool(x) for x in xs if x is not None]
    return (100.0 * sum(xs) / len(xs), len(xs)) if xs else (float("nan"), 0)


def summarise(rows) -> tuple[dict, str]:
    out = {}
    lines = ["| histories | time-to-limit 95 % coverage | steps found within one test | "
             "false step reports | models chosen |", "|---|---|---|---|---|"]
    for label, sel in [(k, [r for r in rows if r["kind"] == k]) for k in KINDS] + [
            ("all", rows)]:
        cov, nc = _pct(r["covered"] for r in sel)
        found, nf = _pct(r.get("step_found") for r in sel if r["step"])
        false, nn = _pct(r.get("false_step") for r in sel if not r["step"])
        models = {}
        for r in sel:
            models[r["model"]] = models.get(r["model"], 0) + 1
        out[label] = dict(coverage_pct=cov, n=nc, steps_found_pct=found, with_step=nf,
                          false_step_pct=false, without_step=nn, models=models)
        lines.append(f"| {label} ({len(sel)}) | {cov:.1f} % ({nc}) | {found:.1f} % ({nf}) | "
                     f"{false:.1f} % ({nn}) | "
                     + ", ".join(f"{k} {v}" for k, v in sorted(models.items(), key=str))
                     + " |")
    return out, "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--histories", type=int, default=600)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rows, start = [], time.monotonic()
    with open(out / "rows.jsonl", "w", encoding="utf-8") as fh:
        for i in range(a.histories):
            rows.append(run_one(i, a.seed))
            fh.write(json.dumps(rows[-1]) + "\n")
            fh.flush()
            if (i + 1) % 50 == 0:
                print(f"{i + 1}/{a.histories} histories ({time.monotonic() - start:.0f} s)",
                      file=sys.stderr, flush=True)
    summary, table = summarise(rows)
    summary.update(histories=a.histories, seed=a.seed,
                   seconds=round(time.monotonic() - start, 1))
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / "summary.md").write_text(table + "\n")
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
