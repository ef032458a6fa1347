"""O1: FRCs by harmonic-balance vs shooting continuation vs a brute-force sweep, and the
cost of the frc_peak design gradient.

(A) default preset, 100 N, 1000-1250 Hz (two folds near 1119-1120 Hz); (B) cold preset,
5000 N, 900-1500 Hz (contact loss; HB needs many harmonics). For each FRC:
`continue_orbits` with `HarmonicBalance` (8 harmonics at the start, doubled as the error
estimate requires, error_tol 1e-4; in the positions alone, `second_order=True`, as the
package runs it on the BSFS, and first order beside it) and with `Shooting()`, both ds = 0.1, ds_max = 1.0,
from the same linear-FRF guess; for (A) also HB at fixed 8 and 16 harmonics. The first
call includes compilation; the warm time is the median over repeats after it. Then a
brute-force cold sweep (`analysis.sweep`) sized to match the HB peak's accuracy (see
`brute_force`). (C): `frc_peak` at 100 N, `OrbitSettings(frc_band=(0.97, 1.0))`: one
evaluation vs value + all 16 gradients, host-side peak search included and alone.
BLAS runs single-threaded (OPENBLAS/OMP/MKL_NUM_THREADS=1 unless set): on a busy 2-core
machine multi-threaded LAPACK makes one 199 x 199 LU take ~120 ms instead of ~1 ms.

Usage: python benchmarks/bench_orbits.py [--quick]   (quick: FRC (A) only, 1 repeat)
Writes benchmarks/results/orbits.md and orbits.json.
"""

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine_info, machine_line  # noqa: E402

from bsfs_jax import design  # noqa: E402
from bsfs_jax.analysis import SweepConfig, bsfs_problem, sweep  # noqa: E402
from bsfs_jax.design import _sensitivity as dsens  # noqa: E402
from bsfs_jax.design.building import linear_guess  # noqa: E402
from bsfs_jax.machine import bsfs_family, modes, simulate  # noqa: E402
from bsfs_jax.model import build_system  # noqa: E402
from bsfs_jax.params import preset  # noqa: E402
from bsfs_jax.solvers import HarmonicBalance, Shooting, continue_orbits  # noqa: E402

RESULTS = Path(__file__).parent / "results"
CASES = {"A": ("default", 100.0, (1000.0, 1250.0)), "B": ("cold", 5000.0, (900.0, 1500.0))}
DS, DS_MAX, MAX_POINTS = 0.1, 1.0, 2000


def timed(fn, repeats):
    """(result, first-call time, median warm time, warm times)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        runs.append(time.perf_counter() - t0)
    return out, first, float(np.median(runs)), runs


def rel(a, b):
    return abs(a - b) / abs(b)


def run_branch(label, family, guess, band, method, repeats):
    def go():
        return continue_orbits(family, guess, band[0], band[1], method=method, ds=DS,
                               ds_max=DS_MAX, max_points=MAX_POINTS, amplitude_index=2)

    br, first, warm, runs = timed(go, repeats)
    pk = br.peak
    row = {"label": label, "first_call_s": first, "warm_s": warm, "warm_runs_s": runs,
           "compile_s_estimate": first - warm, "points": len(br),
           "corrector_calls": br.info["corrector_calls"], "rejected": br.info["rejected"],
           "stop_reason": br.info["stop_reason"], "harmonics": br.info.get("harmonics"),
           "harmonic_upgrades": br.info.get("harmonic_upgrades"),
           "max_error_estimate": float(np.max(br.error_estimates)),
           "folds_hz": sorted(b.p for b in br.bifurcations if b.kind == "fold"),
           "other_bifurcations": [(b.kind, b.p) for b in br.bifurcations if b.kind != "fold"],
           "peak_hz": None if pk is None else pk.p,
           "peak_um": None if pk is None else pk.amplitude * 1e6}
    print(f"  {label}: first {first:.1f} s, warm {warm:.2f} s, {len(br)} points, H="
          f"{row['harmonics']}, folds {row['folds_hz']}, peak {row['peak_um']} um", flush=True)
    return br, row


def compare(row, ref):
    """Accuracy and speed of `row` against the shooting branch `ref`."""
    same = len(row["folds_hz"]) == len(ref["folds_hz"])
    fold_rel = [rel(a, b) for a, b in zip(row["folds_hz"], ref["folds_hz"])] if same else None
    peak = row["peak_um"] is not None and ref["peak_um"] is not None
    row.update({"fold_rel_diff": fold_rel,
                "peak_amp_rel_diff": rel(row["peak_um"], ref["peak_um"]) if peak else None,
                "peak_freq_rel_diff": rel(row["peak_hz"], ref["peak_hz"]) if peak else None,
                "speed_ratio_shooting_over_this": ref["warm_s"] / row["warm_s"]})


def curvature(branch, pk):
    """|d2A/df2| at the peak [m/Hz^2]: parabola through the peak and its neighbours on the
    branch (the monotone-in-f stretch around it, at most 3 points each side)."""
    p, a, i = branch.p, branch.amplitude, pk.index
    sign = np.sign(p[i + 1] - p[i])
    lo, hi = i, i + 1
    while lo > 0 and i - lo < 2 and np.sign(p[lo] - p[lo - 1]) == sign:
        lo -= 1
    while hi < len(p) - 1 and hi - i < 3 and np.sign(p[hi + 1] - p[hi]) == sign:
        hi += 1
    f = np.concatenate([p[lo:hi + 1], [pk.p]])
    amp = np.concatenate([a[lo:hi + 1], [pk.amplitude]])
    return abs(2.0 * np.polyfit(f - pk.p, amp, 2)[0]), int(f.size)


def settle_periods(params, force, pk, tol, n_max):
    """Periods from rest at the peak frequency after which the strobe stays within `tol`
    of its final value (|dx_n| / A*, |dv_n| / its amplitude), and the final distance to
    the peak orbit; None for the periods if the run ends on another orbit."""
    y = np.asarray(simulate(params, frequency_hz=pk.p, force_n=force, transient_periods=0,
                            periods=n_max, samples_per_period=1).state)
    def dist(ref):
        return np.maximum(np.abs(y[:, 2] - ref[2]) / pk.amplitudes[2],
                          np.abs(y[:, 5] - ref[5]) / pk.amplitudes[5])
    e_end = float(dist(pk.state)[-1])
    bad = np.nonzero(dist(y[-1]) > tol)[0]
    n = int(bad[-1]) + 1 if bad.size else 0
    return (n if e_end < 1e-3 and n < n_max - 10 else None), e_end


def brute_force(params, force, band, ref_branch, eps, max_timed, rows_hb):
    """Cold sweep matching the HB peak's relative accuracy `eps` (see the notes in the
    markdown): transient and sampling each to eps / 4, the grid step from a parabola and
    then shrunk until 8 points spaced h around the peak (offset h / 2) find A* within eps.
    Times up to `max_timed` points spread evenly over the band, scaled to the grid."""
    pk = ref_branch.peak
    m = modes(build_system(params))
    sigma_lin = float(m.damping_ratios[0] * 2 * np.pi * m.frequencies_hz[0])
    sigma_floq = float(-np.log(np.max(np.abs(pk.point.mu))) * pk.p)
    n_floq = math.ceil(math.log(4.0 / eps) / min(sigma_lin, sigma_floq) * pk.p)
    n_tr, e_end = settle_periods(params, force, pk, eps / 4, max(1000, 10 * n_floq))
    spp = 2 ** math.ceil(math.log2(math.pi / math.sqrt(eps / 2)))
    c, n_fit = curvature(ref_branch, pk)
    h0 = h = math.sqrt(8.0 * eps * pk.amplitude / c)
    cfg = SweepConfig(transient_periods=n_tr or n_floq, periods=1, samples_per_period=spp,
                      lyapunov=False, batch_size=8, chunk_size=8)
    problem = bsfs_problem(params, "frequency_hz", force_n=force)
    t0 = time.perf_counter()
    sweep(problem, np.linspace(band[1] - 1.0, band[1], 8), config=cfg, progress=False)
    compile_s = time.perf_counter() - t0
    for _ in range(8 if n_tr is not None else 1):
        local = pk.p + h * (np.arange(-4, 4) + 0.5)
        amps = sweep(problem, local, config=cfg, progress=False).amplitude[0, :, 2]
        err = rel(float(np.nanmax(amps)), pk.amplitude)
        if err <= eps or n_tr is None:
            break
        h /= math.sqrt(2.0)
    n_grid = math.ceil((band[1] - band[0]) / h) + 1
    n_timed = min(n_grid, max_timed)
    t0 = time.perf_counter()
    res = sweep(problem, np.linspace(band[0], band[1], n_timed), config=cfg, progress=False)
    t_timed = time.perf_counter() - t0
    grid_amp = res.amplitude[0, :, 2]
    out = {"eps": eps, "sigma_linear_per_s": sigma_lin, "sigma_floquet_peak_per_s": sigma_floq,
           "transient_periods_floquet_estimate": n_floq, "transient_periods": n_tr,
           "reaches_peak_orbit": n_tr is not None, "strobe_distance_at_end": e_end,
           "samples_per_period": spp, "curvature_um_per_hz2": c * 1e6,
           "curvature_fit_points": n_fit, "grid_step_parabola_hz": h0, "grid_step_hz": h,
           "grid_points": n_grid, "timed_points": n_timed, "timed_s": t_timed,
           "compile_and_warmup_s": compile_s, "failed_timed": int(np.sum(res.failed)),
           "estimated_full_grid_s": t_timed * n_grid / n_timed, "scaled": n_timed < n_grid,
           "local_peak_rel_err": err, "timed_grid_max_um": float(np.nanmax(grid_amp)) * 1e6,
           "timed_grid_max_hz": float(res.values[int(np.nanargmax(grid_amp))])}
    out["ratio_sweep_over_hb"] = {r["label"]: out["estimated_full_grid_s"] / r["warm_s"]
                                  for r in rows_hb}
    print(f"  sweep: eps {eps:.1e}, transient {n_tr} periods (Floquet estimate {n_floq}), "
          f"{spp} samples/period, h {h:.3g} Hz (parabola {h0:.3g}) -> {n_grid} points; "
          f"{n_timed} timed in {t_timed:.2f} s -> {out['estimated_full_grid_s']:.1f} s; "
          f"local peak rel err {err:.1e}", flush=True)
    return out


def run_case(name, repeats, quick):
    preset_name, force, band = CASES[name]
    print(f"FRC ({name}): {preset_name} preset, {force:g} N, {band[0]:g}-{band[1]:g} Hz",
          flush=True)
    params = preset(preset_name)
    family = bsfs_family(params, force)
    args, _ = family(band[0])
    guess = linear_guess(args[0], args[1])
    # Harmonic balance as the package runs it on the BSFS: in the positions alone
    # (second_order; the same orbits, half the unknowns), and first order beside it.
    variants = [("HB adaptive (start 8)", HarmonicBalance(harmonics=8, second_order=True)),
                ("HB adaptive (start 8), first order", HarmonicBalance(harmonics=8))]
    if name == "A":
        # error_tol=1: no harmonic check, else the run stops where the estimate exceeds it.
        variants += [(f"HB fixed {h}", HarmonicBalance(harmonics=h, max_harmonics=h,
                                                       error_tol=1.0, second_order=True))
                     for h in (8, 16)]
    rows = []
    sh_branch, sh = run_branch("shooting", family, guess, band, Shooting(), repeats)
    for label, method in variants:
        _, row = run_branch(label, family, guess, band, method, repeats)
        compare(row, sh)
        rows.append(row)
    eps = max(rows[0]["peak_amp_rel_diff"], 1e-6)  # the adaptive HB's peak error
    bf = brute_force(params, force, band, sh_branch, eps, 256 if quick else 4096, rows)
    return {"preset": preset_name, "force_n": force, "band_hz": list(band),
            "shooting": sh, "hb": rows, "brute_force": bf}


def design_gradient(repeats, api):
    params = preset("default")
    settings = design.OrbitSettings(frc_band=(0.97, 1.0))
    metric, names = design.get_metric("frc_peak"), design.DESIGN_PARAMETERS
    op = dsens.operating_point(metric, None, 100.0)
    value_fn, vg_fn = design.compiled("frc_peak", names, settings)
    theta = jnp.asarray(dsens.parameter_values(params, names))
    kw = {"force_n": 100.0, "settings": settings}
    hint, t_loc_first, t_loc, _ = timed(
        lambda: dsens.locate_hint(metric, params, op, settings), repeats)
    value, t_val_first, t_val, _ = timed(lambda: value_fn(theta, params, op, hint), repeats)
    (_, grad), t_vg_first, t_vg, _ = timed(lambda: vg_fn(theta, params, op, hint), repeats)
    t_eval_api = t_sens_api = None  # the public API end to end (full mode only)
    if api:
        _, _, t_eval_api, _ = timed(lambda: design.evaluate("frc_peak", params, **kw),
                                    repeats)
        _, _, t_sens_api, _ = timed(
            lambda: design.sensitivities("frc_peak", params, names, **kw), repeats)
    out = {"parameters": len(names), "value_um": float(value) * 1e6,
           "peak_hz": float(hint.frequency_hz), "method": repr(hint.method),
           "locate_s": t_loc, "value_jit_s": t_val, "value_and_grad_jit_s": t_vg,
           "first_calls_s": {"locate": t_loc_first, "value": t_val_first,
                             "value_and_grad": t_vg_first},
           "one_evaluation_s": t_loc + t_val, "value_and_all_gradients_s": t_loc + t_vg,
           "api_evaluate_s": t_eval_api, "api_sensitivities_s": t_sens_api,
           "gradient_finite": bool(np.all(np.isfinite(np.asarray(grad))))}
    out["ratio_total"] = out["value_and_all_gradients_s"] / out["one_evaluation_s"]
    out["ratio_jitted"] = t_vg / t_val
    out["ratio_api"] = t_sens_api / t_eval_api if api else None
    print(f"(C) frc_peak: locate {t_loc:.2f} s, value {t_val * 1e3:.2f} ms, value+grad "
          f"{t_vg * 1e3:.2f} ms; ratio {out['ratio_total']:.3f} (jitted "
          f"{out['ratio_jitted']:.2f}, API {out['ratio_api']})", flush=True)
    return out


def met(ok):
    return "met" if ok else "**NOT met**"


def fmt_list(xs, f="{:.4f}"):
    return "n/a" if xs is None else ", ".join(f.format(x) for x in xs)


def markdown(data):
    q = " (quick run: FRC (A) only, 1 repeat)" if data["quick"] else ""
    lines = ["## O1 Periodic orbits", "",
             "Command: `python benchmarks/bench_orbits.py`.",
             machine_line(data["machine"]) + f" BLAS threads: {data['blas_threads']}; load "
             f"average at start {', '.join('%.1f' % x for x in data['load_average_at_start'])}"
             " (shared machine: compare ratios, not seconds).", "",
             f"`continue_orbits`, ds = {DS}, ds_max = {DS_MAX}, amplitude x_n, same linear-FRF "
             f"guess. Warm time = median of {data['repeats']} run(s) after a first call "
             f"(which includes compilation){q}. Ratio = shooting time / this time; target "
             ">= 20 for HB; fold frequencies vs shooting within 1e-4.", "",
             "| FRC | method | first call [s] | warm [s] | points | corrector calls | final H "
             "| max error est. | folds [Hz] | peak [um] at [Hz] | fold rel. diff | peak amp. "
             "rel. diff | shooting / this | target >= 20x |", "|" + "---|" * 14]
    for name, c in data["frc"].items():
        for r in [c["shooting"]] + c["hb"]:
            hb = r["label"] != "shooting"
            pk = "none" if r["peak_um"] is None else f"{r['peak_um']:.5f} at {r['peak_hz']:.3f}"
            lines.append(
                f"| {name} | {r['label']} | {r['first_call_s']:.1f} | {r['warm_s']:.3g} | "
                f"{r['points']} | {r['corrector_calls']} | {r['harmonics'] or '-'} | "
                f"{r['max_error_estimate']:.1e} | {fmt_list(r['folds_hz'], '{:.3f}')} | {pk} | "
                + (f"{fmt_list(r['fold_rel_diff'], '{:.1e}')} | "
                   f"{r['peak_amp_rel_diff']:.1e} | {r['speed_ratio_shooting_over_this']:.2f} | "
                   f"{met(r['speed_ratio_shooting_over_this'] >= 20)} |" if hb
                   else "(reference) | | 1 | |"))
    lines += ["", "Brute-force cold sweep at matching accuracy (`analysis.sweep`, dopri5-fused, "
              "rtol 1e-8, from rest at every frequency). \"Matching accuracy\": eps = the HB "
              "peak's relative amplitude error against shooting (floor 1e-6); the sweep's "
              "peak amplitude must be within eps of the shooting peak A*. Transient: the "
              "periods after which a run from rest at the peak frequency stays within eps/4 "
              "of the peak orbit (measured at the strobe; the Floquet-rate estimate "
              "ln(4/eps)/sigma is too short: the build-up from rest is slower); samples per "
              "period with 1 - cos(pi/spp) <= eps/4; grid step h first from a parabola "
              "fitted to the shooting branch (|A''| h^2/8 = eps A*), then shrunk by sqrt(2) "
              "until 8 points spaced h around the peak, offset by h/2 (the worst case), find "
              "A* within eps. Both calibrations use the shooting reference, which a real "
              "sweep would not have (generous to the sweep). Times over more points than "
              "timed are scaled linearly from points spread evenly over the band "
              "(\"scaled\").", "",
              "| FRC | eps | transient periods (Floquet est.) | samples/period | h [Hz] "
              "(parabola) | grid points | timed points in [s] | full grid [s] | sweep / HB "
              "adaptive | peak found (rel. err.) |", "|" + "---|" * 10]
    for name, c in data["frc"].items():
        b = c["brute_force"]
        found = (f"{b['local_peak_rel_err']:.1e}" if b["reaches_peak_orbit"] else
                 f"**no**: from rest it settles on another orbit (strobe distance "
                 f"{b['strobe_distance_at_end']:.2f} A*); grid max {b['timed_grid_max_um']:.4g}"
                 f" um at {b['timed_grid_max_hz']:.1f} Hz")
        lines.append(
            f"| {name} | {b['eps']:.1e} | {b['transient_periods'] or 'n/a'} "
            f"({b['transient_periods_floquet_estimate']}) | {b['samples_per_period']} | "
            f"{b['grid_step_hz']:.3g} ({b['grid_step_parabola_hz']:.3g}) | {b['grid_points']} "
            f"| {b['timed_points']} in {b['timed_s']:.2f} | {b['estimated_full_grid_s']:.1f}"
            f"{' (scaled)' if b['scaled'] else ''} | "
            f"{b['ratio_sweep_over_hb']['HB adaptive (start 8)']:.2f} | {found} |")
    lines += ["", "A sweep finds neither the unstable branch nor the folds' exact location "
              "(only a jump between two grid points), and cold starts in a hysteresis "
              "band may settle on either coexisting orbit; the continuations give both "
              "branches, the folds (located by regula falsi) and the Floquet multipliers."]
    d = data.get("design")
    if d:
        lines += ["", "(C) `frc_peak` (default preset, 100 N, `OrbitSettings(frc_band=(0.97, "
                  "1.0))`, other settings default): "
                  f"{d['value_um']:.5f} um at {d['peak_hz']:.3f} Hz (peak located with "
                  f"`{d['method']}`, the default `frc_method`'s choice); "
                  f"{d['parameters']} design parameters. Medians of {data['repeats']} run(s) "
                  "after the first call.", "",
                  "| part | one evaluation [s] | value + all gradients [s] | ratio | target "
                  "<= 5x |", "|---|---|---|---|---|",
                  f"| host peak search (continuation) + jitted evaluation | "
                  f"{d['one_evaluation_s']:.3f} | {d['value_and_all_gradients_s']:.3f} | "
                  f"{d['ratio_total']:.3f} | {met(d['ratio_total'] <= 5)} |",
                  f"| jitted parts alone (value_fn vs value_and_grad_fn) | "
                  f"{d['value_jit_s']:.2e} | {d['value_and_grad_jit_s']:.2e} | "
                  f"{d['ratio_jitted']:.2f} | {met(d['ratio_jitted'] <= 5)} |",
                  f"| public API: `evaluate` vs `sensitivities` | {d['api_evaluate_s']:.3f} | "
                  f"{d['api_sensitivities_s']:.3f} | {d['ratio_api']:.3f} | "
                  f"{met(d['ratio_api'] <= 5)} |" if d["ratio_api"] is not None
                  else "| public API (full mode only) | | | | |", "",
                  f"Host search alone: {d['locate_s']:.2f} s. First calls (compilation): "
                  f"locate {d['first_calls_s']['locate']:.1f} s (less what the FRC runs "
                  f"above compiled), value {d['first_calls_s']['value']:.1f} s, value+grad "
                  f"{d['first_calls_s']['value_and_grad']:.1f} s."]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="FRC (A) only, 1 repeat")
    ap.add_argument("--repeats", type=int, default=None, help="warm repeats (default 1/3)")
    ap.add_argument("--cases", nargs="*", default=None, help="FRCs to run (A, B)")
    ap.add_argument("--no-design", action="store_true", help="skip (C)")
    opts = ap.parse_args(argv)
    repeats = opts.repeats or (1 if opts.quick else 3)
    cases = opts.cases or (["A"] if opts.quick else ["A", "B"])
    data = {"machine": machine_info(), "quick": opts.quick, "repeats": repeats,
            "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
            "load_average_at_start": os.getloadavg(), "ds": DS, "ds_max": DS_MAX,
            "frc": {name: run_case(name, repeats, opts.quick) for name in cases}}
    if not opts.no_design:
        data["design"] = design_gradient(repeats, api=not opts.quick)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "orbits.json").write_text(json.dumps(data, indent=2) + "\n")
    md = markdown(data)
    (RESULTS / "orbits.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
