#!/usr/bin/env bash
# Round 29: both MVS networks fine-tuned side by side on one GPU from the shipped weights, for
# as many steps as fit SECONDS each (a timing run of 110 steps sets the number), on the packs
# in DATA. Runs where torch and a GPU are, without the app's GL packages
# (scripts/train_elsewhere.py). Weights and logs go to OUT/u (unguided, preset mvs) and OUT/g
# (mono-guided, preset full).
#
#   bash scripts/train_mvs_gpu.sh DATA OUT SECONDS
#
# (BATCH=2 DEVICE=cpu: a smoke run of the script here. FEATURES=0.5: the mono-guided network
# also gets out-of-domain monocular features for half its pairs, `--mono-features-shift`,
# round 30's lever; default 0, round 29's recipe.)
set -euo pipefail
data=$1 out=$2 seconds=$3
py=${PYTHON:-python3}
train=(scripts/train_elsewhere.py train depth --data "$data" --stage mvs --trunk 2
       --batch "${BATCH:-16}" --lr 3e-4 --device "${DEVICE:-cuda}" --threads 7)
u=(--preset mvs --init assets/depth_mvs_only.safetensors)
g=(--preset full --init assets/depth_mvs_full.safetensors --mono assets/depth_mono.safetensors
   --mono-noise 0.8 --mono-shift 0.3 --mono-warp 0.3 --mono-features-shift "${FEATURES:-0}")
mkdir -p "$out/u" "$out/g" "$out/timing"

# Timing: both at once, as in the real run; seconds per step from step 50 to 100.
"$py" "${train[@]}" "${u[@]}" --steps 110 --limit-scenes 200 --out "$out/timing/u.safetensors" \
    --log "$out/timing/u.log" >/dev/null &
"$py" "${train[@]}" "${g[@]}" --steps 110 --limit-scenes 200 --out "$out/timing/g.safetensors" \
    --log "$out/timing/g.log" >/dev/null &
wait
steps_for() {
    awk -v s="$seconds" '$1 == "step" && $2 == 50 {a = $(NF-1)} $1 == "step" && $2 == 100 {b = $(NF-1)}
        END {n = int(s / ((b - a) / 50)); print (n > 200 ? n : 200)}' "$1"
}
nu=$(steps_for "$out/timing/u.log") ng=$(steps_for "$out/timing/g.log")
echo "steps: unguided $nu, mono-guided $ng"

"$py" "${train[@]}" "${u[@]}" --steps "$nu" --out "$out/u/depth_mvs_only.safetensors" \
    --log "$out/u/depth_mvs_only_gpu.log" >/dev/null &
"$py" "${train[@]}" "${g[@]}" --steps "$ng" --out "$out/g/depth_mvs_full.safetensors" \
    --log "$out/g/depth_mvs_full_gpu.log" >/dev/null &
wait
tail -n 3 "$out/u/depth_mvs_only_gpu.log" "$out/g/depth_mvs_full_gpu.log"
