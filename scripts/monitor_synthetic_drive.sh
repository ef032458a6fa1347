#!/usr/bin/env bash
# A drive whose nut preload falls linearly, 1500 N new, by 0.25 N/h (900 N at 2400 h):
# six tests 400 h apart, each one 1 s chirp record (bsfs synth) identified by bsfs identify,
# then monitored against a 900 N limit. The true crossing is 2400 h.
#   bash scripts/monitor_synthetic_drive.sh OUT_DIR
set -euo pipefail
out=${1:?usage: monitor_synthetic_drive.sh OUT_DIR}
bsfs=${BSFS:-bsfs}
mkdir -p "$out"
echo "folder,hours" > "$out/manifest.csv"
for i in 0 1 2 3 4 5; do
  h=$((400 * i))
  preload=$(python3 -c "print(1500.0 - 0.25 * $h)")
  "$bsfs" synth --set nut.preload_n="$preload" --excitation chirp --start 50 --stop 2500 \
    --force 5 --duration 1 --seed "$i" --out "$out/test_$h.csv" --overwrite
  "$bsfs" identify "$out/test_$h.csv" --fit nut_preload,bearing_preload,c_b,c_s,c_n \
    --out "$out/test_$h"
  echo "test_$h,$h" >> "$out/manifest.csv"
done
"$bsfs" monitor --manifest "$out/manifest.csv" --limit nut_preload=900 --next-test 2400 \
  --out "$out/monitor"
