#!/usr/bin/env bash
# Round 45's third call on a lent GPU: renders replayed from CUDA graphs
# (`panogrf.renderer.graphs`) against launched ones, one process after the other on the same
# machine; the CUDA tests; the CPU parity with the refinement damped (`RefineConfig.damping`).
# Carried: data/loo_lit, data/gpu_test. Usage: bash lab/gpu/round45c.sh
set -u
mkdir -p /tmp/pk && ln -sfn "$PWD" /tmp/pk/panogrf
export PYTHONPATH=/tmp/pk PYTHONUNBUFFERED=1
echo "=== tests"
timeout 100 python3 -m pytest -q -p no:cacheprovider -m gpu tests/model tests/renderer \
  tests/app/test_device.py > "$OUT/tests.log" 2>&1
echo "rc $?"; tail -4 "$OUT/tests.log"
bench() {  # name data args...
  local name=$1 data=$2; shift 2
  echo "=== $name"
  timeout 150 python3 benchmarks/gpu.py --data "$data" --device cuda --tf32 off \
    --out "$OUT/$name.json" "$@" > "$OUT/$name.log" 2>&1
  echo "rc $?"; grep -E "live:|'scene'|Error" "$OUT/$name.log" | cut -c1-240
  grep -E "warm|fast_|paper_|memory" "$OUT/$name.log" | tail -7
}
bench off data/loo_lit --scenes 4 --cpu-scenes 0 --live --render-graphs off
bench on data/loo_lit --scenes 4 --cpu-scenes 0 --live --render-graphs on
bench off2 data/loo_lit --scenes 4 --cpu-scenes 0 --live --render-graphs off
bench on2 data/loo_lit --scenes 4 --cpu-scenes 0 --live --render-graphs on
bench parity data/gpu_test --scenes 6 --parity
