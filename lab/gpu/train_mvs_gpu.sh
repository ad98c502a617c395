#!/usr/bin/env bash
# Round 29: both MVS networks fine-tuned side by side on one GPU from the shipped weights, for
# as many steps as fit SECONDS each (a timing run of 110 steps sets the number), on the packs
# in DATA. Runs where torch and a GPU are, without the app's GL packages
# (lab/gpu/train_elsewhere.py). Weights and logs go to OUT/u (unguided, preset mvs) and OUT/g
# (mono-guided, preset full).
#
#   bash lab/gpu/train_mvs_gpu.sh DATA OUT SECONDS
#
# BATCH=2 DEVICE=cpu: a smoke run of the script here. FEATURES=P: the mono-guided network also
# gets out-of-domain monocular features for a fraction P of its pairs, `--mono-features-shift`,
# round 30's lever (default 0, round 29's recipe). RUNS="g gf" (round 31): instead of the two
# networks, two mono-guided runs side by side, OUT/g as round 29's recipe (the control) and
# OUT/gf with FEATURES (default 0.5 there; the candidate). RUNS=gf (round 35): that candidate
# alone, with the whole device to itself. INIT=FILE: the mono-guided runs start from FILE instead
# of the shipped weights (to train an earlier run on).
set -euo pipefail
data=$1 out=$2 seconds=$3
py=${PYTHON:-python3}
runs=(${RUNS:-u g})
train=(lab/gpu/train_elsewhere.py train depth --data "$data" --stage mvs --trunk 2
       --batch "${BATCH:-16}" --lr 3e-4 --device "${DEVICE:-cuda}" --threads 7)
guided=(--preset full --init "${INIT:-assets/depth_mvs_full.safetensors}" --mono assets/depth_mono.safetensors
        --mono-noise 0.8 --mono-shift 0.3 --mono-warp 0.3)
case ${runs[*]} in
    "u g" | "g gf" | gf) ;;
    *) echo "RUNS is 'u g', 'g gf' or 'gf'" >&2; exit 2 ;;
esac
if [[ ${runs[*]} == "g gf" ]]; then features_g=0; else features_g=${FEATURES:-0}; fi
declare -A weights=([u]=depth_mvs_only [g]=depth_mvs_full [gf]=depth_mvs_full)
run_args() {  # the arguments of one run, by name
    case $1 in
        u) echo --preset mvs --init assets/depth_mvs_only.safetensors ;;
        g) echo "${guided[@]}" --mono-features-shift "$features_g" ;;
        gf) echo "${guided[@]}" --mono-features-shift "${FEATURES:-0.5}" ;;
    esac
}
mkdir -p "$out/timing"

# Timing: both at once, as in the real run; seconds per step from step 50 to 100.
for r in "${runs[@]}"; do
    # shellcheck disable=SC2046
    "$py" "${train[@]}" $(run_args "$r") --steps 110 --limit-scenes 200 \
        --out "$out/timing/$r.safetensors" --log "$out/timing/$r.log" >/dev/null &
done
wait
steps_for() {
    awk -v s="$seconds" '$1 == "step" && $2 == 50 {a = $(NF-1)} $1 == "step" && $2 == 100 {b = $(NF-1)}
        END {n = int(s / ((b - a) / 50)); print (n > 200 ? n : 200)}' "$1"
}
logs=()
for r in "${runs[@]}"; do
    n=$(steps_for "$out/timing/$r.log")
    echo "steps: $r $n"
    mkdir -p "$out/$r"
    logs+=("$out/$r/${weights[$r]}_gpu.log")
    # shellcheck disable=SC2046
    "$py" "${train[@]}" $(run_args "$r") --steps "$n" --out "$out/$r/${weights[$r]}.safetensors" \
        --log "$out/$r/${weights[$r]}_gpu.log" >/dev/null &
done
wait
tail -n 3 "${logs[@]}"
