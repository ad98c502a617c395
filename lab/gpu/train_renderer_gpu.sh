#!/usr/bin/env bash
# Round 32: the renderer (`renderer_panogrf`) fine-tuned on one GPU from the shipped weights, for
# as many steps as fit SECONDS (a timing run of 110 steps on 200 scenes sets the number), on
# the packs in DATA (colour-only packs at 256 rows will do: `panogrf dataset pack --height 256
# --colour-only`). The depth networks estimate every training pair's depth there first (cached
# in DATA). Runs where torch and a GPU are, without the app's GL packages
# (lab/gpu/train_elsewhere.py). Weights and log go to OUT/r.
#
#   bash lab/gpu/train_renderer_gpu.sh DATA OUT SECONDS
#
# SCENES, RAYS (default 8 and 1024): scenes per step and rays per scene; LR (default 3e-4);
# INIT (default the shipped weights): the weights it starts from; STEPS=N: N steps, no timing
# run (SECONDS is then ignored). DEVICE=cpu SCENES=1 RAYS=32: a smoke run of the script here.
set -euo pipefail
data=$1 out=$2 seconds=$3
py=${PYTHON:-python3}
train=(lab/gpu/train_elsewhere.py train renderer --data "$data" --preset panogrf
       --init "${INIT:-assets/renderer_panogrf.safetensors}" --scenes "${SCENES:-8}" --rays "${RAYS:-1024}"
       --lr "${LR:-3e-4}" --device "${DEVICE:-cuda}" --threads 8)
mkdir -p "$out/timing" "$out/r"

if [[ -n ${STEPS:-} ]]; then
    n=$STEPS
else
    # Timing: seconds per step from step 50 to 100.
    "$py" "${train[@]}" --steps 110 --limit-scenes 200 --out "$out/timing/r.safetensors" \
        --log "$out/timing/r.log" >/dev/null
    n=$(awk -v s="$seconds" '$1 == "step" && $2 == 50 {a = $(NF-1)} $1 == "step" && $2 == 100 {b = $(NF-1)}
        END {n = int(s / ((b - a) / 50)); print (n > 200 ? n : 200)}' "$out/timing/r.log")
fi
echo "steps: $n"
"$py" "${train[@]}" --steps "$n" --out "$out/r/renderer_panogrf.safetensors" \
    --log "$out/r/renderer_panogrf_gpu.log" >/dev/null
tail -n 3 "$out/r/renderer_panogrf_gpu.log"
