#!/usr/bin/env bash
# Round 41 on a lent GPU: the chain as it is (new) against main at d1afb5a (old), same machine,
# one after the other: where a render's milliseconds go (lab/gpu/render_parts.py), a new scene
# end to end, renders and the live worker (benchmarks/gpu.py), the CPU parity on six scenes,
# the CUDA tests. Usage (device machine, repository root): bash lab/gpu/round41.sh, with
# lab/gpu/base_d1afb5a.tar made by: git archive -o lab/gpu/base_d1afb5a.tar d1afb5a app model
# renderer benchmarks shaders
set -u
REPO=$PWD
mkdir -p /tmp/pk /tmp/pkold/panogrf
ln -sfn "$REPO" /tmp/pk/panogrf
tar -xf lab/gpu/base_d1afb5a.tar -C /tmp/pkold/panogrf
ln -sfn "$REPO/assets" /tmp/pkold/panogrf/assets
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
python3 -c "import torch; print(torch.__version__, torch.cuda.get_device_name())"
echo "=== parts"
PYTHONPATH=/tmp/pk timeout 100 python3 lab/gpu/render_parts.py --data data/loo_lit \
  --out "$OUT/parts" 2>&1 | grep " ms$"
run() {  # name pythonpath dir args...
  local name=$1 pp=$2 dir=$3; shift 3
  echo "=== $name"
  (cd "$dir" && PYTHONPATH=$pp timeout 150 python3 benchmarks/gpu.py --data "$REPO/data/loo_lit" \
    --device cuda --tf32 off --out "$OUT/$name.json" "$@") > "$OUT/$name.log" 2>&1
  echo "rc $?"; grep -E "live:|new scene|render |memory|between|'scene'" "$OUT/$name.log"
}
run new /tmp/pk "$REPO" --scenes 4 --cpu-scenes 0 --live
run old /tmp/pkold /tmp/pkold/panogrf --scenes 4 --cpu-scenes 0 --live
run new2 /tmp/pk "$REPO" --scenes 4 --cpu-scenes 0 --live
run parity /tmp/pk "$REPO" --scenes 6 --parity
echo "=== tests"
PYTHONPATH=/tmp/pk timeout 100 python3 -m pytest -q -p no:cacheprovider -m gpu tests/model \
  tests/app/test_device.py 2>&1 | tail -3
