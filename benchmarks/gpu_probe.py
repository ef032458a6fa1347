"""Where a step of the per-lane kernel goes: resources and field variants.

For each variant of the right-hand side, the kernel (`solvers.integrate_lanes`) is traced,
compiled and timed on a short B1 horizon (the same points, 5000 N, 100-4000 Hz, cold from
rest, `--periods` transient periods + 8 samples): the slowest lane's steps and microseconds
per step. Run one variant per process (`--variants NAME`) where a compile might fail.

Variants (all the same equations; "fast" = the kernel's controller arithmetic,
`integrate_lanes(fast=True)`):
- `kernel`: `model.kernel_vector_field` (no float64 division or square root), fast: what
  the sweep's kernel engine runs;
- `kernel_exactctl`: the same field with the exact controller arithmetic;
- `exact`: `model.vector_field_components` (correctly rounded divisions and square roots),
  exact controller: the kernel as it was before the fast forms;
- `mass_divide`: the fast force law, the accelerations divided by the masses, fast;
- `nosine`: the kernel field with a cheap smooth periodic forcing instead of the sine
  (64 x^3 (1 - x)^3 of the phase fraction x, no transcendental; measures the sine), fast;
- `linear`: a linear 3-DOF oscillator (the loop's own cost without the force law), fast.

A variant may carry `@U`: `integrate_lanes(unroll=U)`, U steps per test of the loop's
condition (`kernel@4`); U = 1 otherwise.

Usage: python benchmarks/gpu_probe.py --out DIR [--points 240] [--periods 20]
       [--variants kernel,kernel_exactctl,exact,mass_divide,nosine,linear]
Each result is one JSON line in DIR/probe.jsonl, printed as it comes.
"""

import argparse
import json
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
# BSFS_PROBE_ROOT: another copy of the package (say, the commit before) to time beside.
sys.path.insert(0, os.environ.get("BSFS_PROBE_ROOT") or str(HERE.parent))


def _fields():
    import jax.numpy as jnp

    from bsfs_jax import physics
    from bsfs_jax.model import kernel_vector_field, vector_field_components

    def mass_divide(t, y, args):
        system, forcing = args
        c, m = system.damping, system.mass
        f_b = physics.pair_force(y[0], system.bearing, fast=True) + c[0] * y[3]
        f_s = system.screw_stiffness * (y[1] - y[0]) + c[1] * (y[4] - y[3])
        f_n = physics.pair_force(y[2] - y[1], system.nut, fast=True) + c[2] * (y[5] - y[4])
        return (y[3], y[4], y[5], (f_s - f_b) / m[0], (f_n - f_s) / m[1],
                (forcing(t) - f_n) / m[2])

    def nosine(t, y, args):
        system, forcing = args
        x = forcing.frequency * t
        x = x - jnp.floor(x)
        value = forcing.amplitude * 64.0 * (x * (1.0 - x)) ** 3
        return kernel_vector_field(t, y, (system, lambda _: value))

    def linear(t, y, args):
        system, forcing = args
        k = 2e8
        c, m = system.damping, system.mass
        f_b = k * y[0] + c[0] * y[3]
        f_s = system.screw_stiffness * (y[1] - y[0]) + c[1] * (y[4] - y[3])
        f_n = k * (y[2] - y[1]) + c[2] * (y[5] - y[4])
        force = forcing.fast(t) if hasattr(forcing, "fast") else forcing(t)
        return (y[3], y[4], y[5], (f_s - f_b) / m[0], (f_n - f_s) / m[1],
                (force - f_n) / m[2])

    return {"kernel": (kernel_vector_field, True), "kernel_exactctl": (kernel_vector_field, False),
            "exact": (vector_field_components, False),
            "mass_divide": (mass_divide, True), "nosine": (nosine, True),
            "linear": (linear, True)}


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True)
    p.add_argument("--points", type=int, default=240)
    p.add_argument("--periods", type=int, default=20)
    p.add_argument("--variants", default="kernel,kernel_exactctl,exact,mass_divide,nosine,linear")
    p.add_argument("--block", type=int, default=32)
    p.add_argument("--warps", type=int, default=1)
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log = open(out / "probe.jsonl", "a")
    t0 = time.perf_counter()

    def emit(row):
        row["elapsed_s"] = round(time.perf_counter() - t0, 2)
        log.write(json.dumps(row) + "\n")
        log.flush()
        print(json.dumps(row), flush=True)

    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from bsfs_jax import preset
    from bsfs_jax.analysis import bsfs_problem
    from bsfs_jax.solvers import integrate_lanes

    dev = jax.devices()[0]
    emit({"case": "machine", "device": str(getattr(dev, "device_kind", dev)),
          "backend": jax.default_backend(), "jax": jax.__version__,
          "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "cpu_threads": os.cpu_count()})
    problem = bsfs_problem(preset("default"), "frequency_hz", force_n=5000.0)
    n = args.points
    freqs = jnp.linspace(100.0, 4000.0, n)
    fields = _fields()
    reference = None
    for spec in args.variants.split(","):
        name, _, unroll = spec.partition("@")
        unroll = int(unroll or 1)
        field, fast = fields[name]
        extra = {"unroll": unroll} if unroll != 1 else {}

        def run(v, field=field, fast=fast, extra=extra):
            a, per = jax.vmap(lambda x: problem.setup(problem.data, x))(v)
            return integrate_lanes(field, jnp.zeros((n, 6)), a, args.periods * per, per,
                                   n_samples=8, samples_per_period=1, rtol=1e-8, atol=1e-12,
                                   max_steps=4_000_000, block=args.block,
                                   num_warps=args.warps, fast=fast, **extra)

        fn = jax.jit(run)
        t = time.perf_counter()
        res = jax.block_until_ready(fn(freqs))
        first = time.perf_counter() - t
        times = []
        for _ in range(3):
            t = time.perf_counter()
            res = jax.block_until_ready(fn(freqs))
            times.append(time.perf_counter() - t)
        run_s = float(np.median(times))
        steps = np.asarray(res[4])
        row = {"case": "variant", "name": name, "unroll": unroll, "fast": fast, "points": n,
               "root": os.environ.get("BSFS_PROBE_ROOT", "this tree"), "block": args.block,
               "warps": args.warps, "first_call_s": round(first, 3), "run_s": run_s,
               "steps_max": int(steps.max()), "failed": int(np.sum(np.asarray(res[3]) != 0)),
               "us_per_step": run_s / max(int(steps.max()), 1) * 1e6}
        if name in ("kernel", "kernel_exactctl", "exact", "mass_divide"):
            s = np.asarray(res[1])
            if reference is None:
                reference = s
            else:
                scale = np.abs(reference).max(axis=(1, 2)) + 1e-300
                row["max_rel_vs_first"] = float(
                    (np.abs(s - reference).max(axis=(1, 2)) / scale).max())
        emit(row)
    emit({"case": "done"})


if __name__ == "__main__":
    main()
