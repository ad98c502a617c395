#!/usr/bin/env bash
# Round 45's second call on a lent GPU: the speed again (a second sample of the machine, on
# the test split's scenes), the CPU parity on six scenes of the test split, and the viewer
# headless on EGL with NVIDIA's driver, the neural view live while moving. Carried:
# data/gpu_test (`panogrf dataset make --out data/gpu_test --split test --count 6 --height
# 512`), .whl (cp312 wheels of moderngl, glcontext, moderngl-window, pyglet, pyglm, trimesh,
# fast-simplification) and .gl (libglvnd's EGL and OpenGL dispatch as Debian packages, fetched
# with apt-get download as the device tool's README says).
set -u
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
  --target /tmp/site .whl/*.whl || exit 1
mkdir -p /tmp/pk && ln -sfn "$PWD" /tmp/pk/panogrf
export PYTHONPATH=/tmp/pk:/tmp/site PYTHONUNBUFFERED=1
export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
bench() {  # name data args...
  local name=$1 data=$2; shift 2
  echo "=== $name"
  timeout 170 python3 benchmarks/gpu.py --data "$data" --device cuda --tf32 off \
    --out "$OUT/$name.json" "$@" > "$OUT/$name.log" 2>&1
  echo "rc $?"; grep -E "live:|'scene'|Error" "$OUT/$name.log" | cut -c1-300
  tail -16 "$OUT/$name.log"
}
bench bench2 data/gpu_test --scenes 5 --cpu-scenes 0 --live
bench parity_test data/gpu_test --scenes 6 --parity
for live in on off; do
  echo "=== view, live $live"
  timeout 100 python3 -m panogrf.app.cli view assets/demo --window headless --device cuda \
    --live $live --size 1024x512 --script "wait*60,w*240" --frames 300 \
    --cache-dir /tmp/viewcache > "$OUT/view_$live.log" 2>&1
  echo "rc $?"; grep -E "renderer:|vendor:|closed after|rror" "$OUT/view_$live.log" | tail -4
done
