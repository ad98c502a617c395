#!/usr/bin/env bash
# Round 45 on a lent GPU: the chain as it is after rounds 42-44 (written-out gradients of the
# warps and the photometric error), checked and measured: the CUDA tests, a new scene end to
# end, renders and the live worker, the CPU parity on six scenes, where a render's time goes
# and where it waits for the device. Usage (device machine, repository root, data/loo_lit
# carried): bash lab/gpu/round45.sh
set -u
mkdir -p /tmp/pk && ln -sfn "$PWD" /tmp/pk/panogrf
export PYTHONPATH=/tmp/pk PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import torch; print(torch.__version__, torch.cuda.get_device_name())"
echo "=== tests"
timeout 120 python3 -m pytest -q -p no:cacheprovider -m gpu tests/model tests/app/test_device.py \
  > "$OUT/tests.log" 2>&1
echo "rc $?"; tail -4 "$OUT/tests.log"
bench() {  # name args...
  local name=$1; shift
  echo "=== $name"
  timeout 170 python3 benchmarks/gpu.py --data data/loo_lit --device cuda --tf32 off \
    --out "$OUT/$name.json" "$@" > "$OUT/$name.log" 2>&1
  echo "rc $?"; grep -E "live:|new scene|render |memory|between|'scene'|Error" "$OUT/$name.log"
  tail -22 "$OUT/$name.log"
}
bench bench --scenes 5 --cpu-scenes 0 --live
bench parity --scenes 6 --parity
echo "=== parts"
timeout 90 python3 lab/gpu/render_parts.py --data data/loo_lit --out "$OUT/parts" 2>&1 | \
  grep -E " ms$|waits|Error|variant" | cut -c1-600
rm -f "$OUT/parts/render_trace.json"
