"""How large the per-lane kernels' programs are, lowered for CUDA on any machine.

The orbit checks on the kernel first carried the whole monodromy matrix on a
lane (6 + 36 components); on an H200 XLA had not finished building that program after
260 s, while the sweep's 6-component lane compiles in seconds. Compile time is only
measurable on a GPU, but the lowered program's size can be read anywhere (jax lowers a
Pallas-Triton kernel for "cuda" without one): this prints it for the sweep's lane, the
column lane the checks use now (`solvers._orbit_check_lanes._tangent`, 12 components)
and the former whole-matrix lane (42).

Usage: python benchmarks/kernel_size.py
"""

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

from bsfs_jax import preset  # noqa: E402
from bsfs_jax.analysis import bsfs_problem  # noqa: E402
from bsfs_jax.solvers import _orbit_check_lanes as checks  # noqa: E402
from bsfs_jax.solvers import integrate_lanes  # noqa: E402


def whole_matrix(field, d):
    """The former lane: (z, Phi) with Phi row-major, Phi' = Dg(z) Phi."""
    def g(t, ws, args):
        z = tuple(ws[:d])
        pairs = [jax.jvp(lambda *zs: field(t, zs, args), z,
                         tuple(ws[d + i * d + j] for i in range(d))) for j in range(d)]
        return tuple(pairs[-1][0]) + tuple(pairs[j][1][i] for i in range(d)
                                           for j in range(d))
    return g


def lowered_chars(problem, field, d, lanes=64):
    def run(values):
        args, period = jax.vmap(lambda v: problem.setup(problem.data, v))(values)
        ones = jnp.ones((lanes, 6))
        return integrate_lanes(field, jnp.zeros((lanes, d)), (args, ones, ones), period,
                               period, n_samples=1, samples_per_period=1, rtol=1e-8,
                               atol=1e-12, max_steps=1000, backend="triton", fast=True)

    low = jax.jit(run).trace(jnp.linspace(100.0, 4000.0, lanes)).lower(
        lowering_platforms=("cuda",))
    return len(low.as_text())


def main():
    problem = bsfs_problem(preset("default"), "frequency_hz", force_n=5000.0)
    g = checks._scaled(problem.component_field)
    for name, field, d in (("sweep's lane (state)", g, 6),
                           ("column lane (state, one column)", checks._tangent(g, 6), 12),
                           ("whole-matrix lane (state, matrix)", whole_matrix(g, 6), 42)):
        print(f"{name:36s} {d:3d} components: {lowered_chars(problem, field, d):>9,d} "
              "characters lowered for CUDA")


if __name__ == "__main__":
    main()
