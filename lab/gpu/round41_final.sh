#!/usr/bin/env bash
# Round 41's last GPU check: the final code's new scene, renders and live worker, and the CPU
# parity on six scenes (benchmarks/gpu.py). Usage: bash lab/gpu/round41_final.sh
set -u
mkdir -p /tmp/pk && ln -sfn "$PWD" /tmp/pk/panogrf
export PYTHONPATH=/tmp/pk
python3 -c "import torch; print(torch.__version__, torch.cuda.get_device_name())"
timeout 150 python3 benchmarks/gpu.py --data data/loo_lit --device cuda --tf32 off --scenes 6 \
  --cpu-scenes 0 --live --out "$OUT/final.json" > "$OUT/final.log" 2>&1
echo "rc $?"; grep -E "live:|new scene|render |memory" "$OUT/final.log"
timeout 150 python3 benchmarks/gpu.py --data data/loo_lit --device cuda --tf32 off --scenes 6 \
  --parity --out "$OUT/final_parity.json" > "$OUT/final_parity.log" 2>&1
echo "rc $?"; grep "'scene'" "$OUT/final_parity.log"
