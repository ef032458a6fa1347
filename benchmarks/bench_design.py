"""D1: cost of all design sensitivities of one metric vs one metric evaluation.

For each metric: the time of one evaluation (value only), of value + all gradients by
implicit reverse-mode differentiation (>= 10 parameters), and of central finite
differences (2 evaluations per parameter), medians over repeats after compilation;
plus the largest relative difference between the AD and FD gradients.

Usage: python benchmarks/bench_design.py [--quick]
Writes benchmarks/results/design.md and design.json.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine_info, machine_line  # noqa: E402

from bsfs_jax import preset  # noqa: E402
from bsfs_jax.design import (
    DESIGN_PARAMETERS,
    METRICS,
    OperatingPoint,
    OrbitSettings,
    compiled,  # noqa: E402
    finite_difference_sensitivities,
)
from bsfs_jax.design.building import locate_hint, parameter_values  # noqa: E402

RESULTS = Path(__file__).parent / "results"


def _median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), times


def bench_metric(name, params, op, settings, repeats):
    """Jitted value vs value + gradient; a metric with a host-side search (the FRC peak's
    continuation) has it timed separately and added to both (it is needed by both)."""
    names = DESIGN_PARAMETERS
    value_fn, vg_fn = compiled(name, names, settings)
    theta = jnp.asarray(parameter_values(params, names))
    metric = METRICS[name]
    t_locate = 0.0
    hint = locate_hint(metric, params, op, settings)
    if metric.locate is not None:
        t_locate, _ = _median_time(lambda: locate_hint(metric, params, op, settings), repeats)
    t0 = time.perf_counter()
    jax.block_until_ready(value_fn(theta, params, op, hint))
    compile_value = time.perf_counter() - t0
    t0 = time.perf_counter()
    value, grad = jax.block_until_ready(vg_fn(theta, params, op, hint))
    compile_grad = time.perf_counter() - t0
    t_value, _ = _median_time(lambda: value_fn(theta, params, op, hint), repeats)
    t_grad, _ = _median_time(lambda: vg_fn(theta, params, op, hint), repeats)
    t_value, t_grad = t_value + t_locate, t_grad + t_locate
    t0 = time.perf_counter()
    fd = finite_difference_sensitivities(name, params, names,
                                         frequency_hz=float(op.frequency_hz),
                                         force_n=float(op.force_n), settings=settings)
    t_fd = time.perf_counter() - t0
    grad = np.asarray(grad) * METRICS[name].scale
    matters = np.abs(fd.normalised) > 1e-6
    rel = np.abs(grad - fd.gradient) / np.maximum(np.abs(fd.gradient), 1e-300)
    return {
        "metric": name, "unit": METRICS[name].unit, "value": float(value) * METRICS[name].scale,
        "parameters": len(names), "compile_value_s": compile_value,
        "compile_value_and_grad_s": compile_grad, "value_s": t_value,
        "value_and_grad_s": t_grad, "ratio_grad_to_value": t_grad / t_value,
        "host_search_s": t_locate,
        "fd_s": t_fd, "fd_evaluations": 2 * len(names) + 1,
        "ratio_fd_to_value_and_grad": t_fd / t_grad,
        "max_rel_diff_ad_fd": float(np.max(np.where(matters, rel, 0.0))),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats, no frc_peak")
    args = parser.parse_args(argv)
    repeats = 3 if args.quick else 7
    params = preset()
    op = OperatingPoint(400.0, 100.0)  # frc_peak uses only the force
    settings = OrbitSettings()
    metrics = ["amplitude", "floquet", "natural_frequency", "static_stiffness",
               "thermal_error", "frf_peak"]
    if not args.quick:
        metrics.insert(0, "frc_peak")
    rows = []
    for name in metrics:
        print(f"benchmarking {name} ...", flush=True)
        rows.append(bench_metric(name, params, op, settings,
                                 1 if name == "frc_peak" and args.quick else repeats))
        print(json.dumps(rows[-1], indent=1), flush=True)
    info = machine_info()
    data = {"machine": info,
            "operating_point": {"frequency_hz": 400.0, "force_n": 100.0},
            "settings": repr(settings), "repeats": repeats, "quick": args.quick,
            "results": rows}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "design.json").write_text(json.dumps(data, indent=2) + "\n")
    lines = [
        "## D1 Design sensitivities", "",
        "Command: `python benchmarks/bench_design.py`.",
        machine_line(info), "",
        f"Default preset; orbit metrics at 400 Hz, 100 N; {len(DESIGN_PARAMETERS)} design "
        f"parameters ({', '.join(DESIGN_PARAMETERS)}). Medians of {repeats} runs after "
        "compilation. AD = value and all gradients in one reverse pass (implicit "
        "differentiation through the periodic orbit / equilibrium); FD = central "
        "differences, 2 evaluations per parameter (one run).", "",
        "| metric | value | one evaluation [s] | value + all gradients (AD) [s] | AD / eval | "
        "FD [s] | FD / AD | max rel. diff. AD vs FD | target AD/eval <= 5 |",
        "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ok = "met" if r["ratio_grad_to_value"] <= 5 else "**NOT met**"
        lines.append(f"| {r['metric']} | {r['value']:.5g} {r['unit']} | {r['value_s']:.4g} | "
                     f"{r['value_and_grad_s']:.4g} | {r['ratio_grad_to_value']:.2f} | "
                     f"{r['fd_s']:.3g} | {r['ratio_fd_to_value_and_grad']:.1f} | "
                     f"{r['max_rel_diff_ad_fd']:.1e} | {ok} |")
    lines += ["", "Compile times (first call) [s]: " + "; ".join(
        f"{r['metric']} {r['compile_value_s']:.1f} (value) / {r['compile_value_and_grad_s']:.1f}"
        " (value+grad)" for r in rows) + "."]
    lines += ["", "frc_peak: the peak is located by harmonic-balance continuation over "
              "0.8-1.2 f1 at 100 N (a host-side search, timed once and added to both "
              "columns); its gradient is one reverse pass through the bordered system at "
              "the peak. " + "; ".join(f"host search {r['host_search_s']:.3g} s"
                                       for r in rows if r["host_search_s"] > 0) + "."]
    (RESULTS / "design.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
