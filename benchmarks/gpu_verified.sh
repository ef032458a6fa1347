#!/bin/bash
# The verified GPU cases on a lent GPU (the `device` tool), one call:
#   1. a verified B1 sweep of 2048 points (kernel engine, wide verification, settle
#      blocks), first call and second call, with the verification's phases (bench_gpu.py
#      case 5): the orbit checks vmapped, then on the kernel (compile events to
#      $OUT/compiles_kernel_checks_1.txt: on 2026-11-29 the former 42-component lane's
#      program had not compiled after 260 s; the GPU's utilisation every 5 s to
#      $OUT/util.txt);
#   2. `bsfs map` over 256 x 256 points (frequency 100-4000 Hz x force 1000-8000 N,
#      verified, no row continuations), cold, in a fresh process; with a fourth argument
#      `--kernel-checks`, its orbit checks on the kernel.
# Usage (device): bash benchmarks/gpu_verified.sh [VERIFY_TIMEOUT_S] [ATLAS_TIMEOUT_S] [N]
#                 [--kernel-checks]
# (defaults 150 s for each of the two verified runs and 240 s for the map: 540 s in all,
# inside one device call of at most 600 s; each verified run skips its second call once
# 100 s are spent)
# Needs the wheels of h5netcdf and tomli_w (the image lacks both) in .whl/, carried:
#   echo /.whl/ >> .git/info/exclude
#   .venv/bin/pip download --no-deps --only-binary=:all: -d .whl h5netcdf==1.8.2 tomli_w==1.2.0
# Environment: KC="1" runs the kernel-checks case alone; LOOPED=0 runs every kernel with
# its stages unrolled (SweepConfig.kernel_looped, looped by default); B1="240,2048" first
# times the cold B1 sweep at those point counts. An ATLAS_TIMEOUT_S of 0 skips the atlas.
# Rows go to $OUT/gpu.jsonl.
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg BSFS_CACHE_DIR=/tmp/bsfs-cache
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD
nvidia-smi --query-gpu=name,clocks.max.sm,driver_version --format=csv,noheader
N=${3:-256}
nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv,noheader -l 5 \
  > "$OUT/util.txt" 2>&1 &
if [ -n "${B1:-}" ]; then  # B1="240,2048": the cold B1 sweep at these point counts first
  JAX_LOG_COMPILES=1 timeout 90 python3 benchmarks/bench_gpu.py --out "$OUT" --smoke 0 \
    --points "$B1" --numba-points "" --vmap-points "" --verify-points "" \
    --looped "${LOOPED:-1}" 2> >(grep -E "XLA compilation|Very slow|rror" | cut -c1-200 \
    > "$OUT/compiles_b1.txt")
fi
if [ "${1:-150}" != 0 ]; then
  for kc in ${KC:-0 1}; do  # the orbit checks vmapped, then on the kernel (each a fresh
    # process; KC="1" runs the kernel case alone)
    JAX_LOG_COMPILES=$kc timeout "${1:-150}" python3 benchmarks/bench_gpu.py --out "$OUT" \
      --smoke 0 --points "" --numba-points "" --vmap-points "" --verify-points 2048 \
      --budget 100 --kernel-checks $kc --looped "${LOOPED:-1}" 2> >(grep -E "XLA compilation|Very slow|rror" \
      | cut -c1-200 > "$OUT/compiles_kernel_checks_$kc.txt")
    echo "{\"case\": \"verified process\", \"kernel_checks\": $kc, \"rc\": $?}" | tee -a "$OUT/gpu.jsonl"
  done
fi
[ "${2:-240}" = 0 ] && exit 0  # no atlas
t0=$(date +%s.%N)
BSFS_PROGRESS=1 timeout "${2:-240}" python3 -c "import sys; from bsfs_jax.cli import run; sys.argv[0] = 'bsfs'; run()" \
  map --x-start 100 --x-stop 4000 --x-num "$N" --y-start 1000 --y-stop 8000 --y-num "$N" \
  --no-bifurcations --engine kernel ${4:-} --out /tmp/atlas 2>&1 | tr '\r' '\n' | grep -v '^$' | tail -25
rc=${PIPESTATUS[0]}
t1=$(date +%s.%N)
echo "{\"case\": \"atlas\", \"grid\": \"${N}x${N}\", \"options\": \"${4:-}\", \"rc\": $rc, \"wall_s\": $(python3 -c "print(round($t1 - $t0, 2))")}" | tee -a "$OUT/gpu.jsonl"
cp /tmp/atlas/summary.json "$OUT/atlas_summary.json" 2>/dev/null
cp /tmp/atlas/motion.png "$OUT/atlas_motion.png" 2>/dev/null
true
