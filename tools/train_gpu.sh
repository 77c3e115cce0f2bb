#!/usr/bin/env bash
# Continue the default weights on a GPU machine: the phase-4 recipe (windows of high-resolution photos at
# crops of up to 320x384) from the shipped weights, with a GPU-sized batch, bf16 and many data workers,
# then the new weights as
# fp16 (the shipped format, about 15 MiB) with the run's config and metrics. Needs only torch with CUDA,
# safetensors, scipy, scikit-image, pyyaml, pillow and tqdm: no install step, run from a checkout.
#   tools/train_gpu.sh OUT_DIR [STEPS] [SECONDS]   # defaults: 1200 steps, stop after 540 s in any case
#   tools/train_gpu.sh --dry-run OUT_DIR            # the same script on the CPU: 4 steps at 64x96
# RECIPE=FILE trains another recipe (default configs/default-lite-synthetic-stage5.yaml;
# configs/default-lite-synthetic-large-crops.yaml: phase 8's views at crops up to 512x640). GUIDE=P sets
# window_guide (default 0, the recipe as it is; 0.5 lets half the samples search their fine stages around
# the true depth, the guided windows of docs/model-card.md). RANDOM_PLACEMENT=true trains stage 1's
# transformer on random placements of its token grid (cvt_random_placement, docs/model-card.md);
# TRAIN_SHIFTS=true on the mean over the placements inference averages (cvt_train_shifts; not both).
# SCENE_BATCHES=true (the default) renders each scene once for all its 5 views, every one a reference in the
# same batch (synthetic_scene_batches; batches of 20, 4 scenes): the renderer, not the GPU, sets the pace,
# and each sample costs one rendered view instead of four (3.8-4.6x less data time, bench/bench_data.py);
# false: samples shuffled one by one, batches of 16.
# Then, on any machine: python bench/eval_default_model.py --checkpoint OUT_DIR/weights/*.safetensors
# --calibrate --json quality.json; python tools/ship_default_weights.py ... (docs/model-card.md).
set -euo pipefail
cd "$(dirname "$0")/.."
export PYTHONPATH=src
PY="${PY:-python3}"
DRY=0
if [[ "${1:-}" == "--dry-run" ]]; then DRY=1; shift; fi
OUT="${1:?usage: tools/train_gpu.sh [--dry-run] OUT_DIR [STEPS] [SECONDS]}"
STEPS="${2:-1200}"
SECONDS_LEFT="${3:-540}"
RUN="$OUT/run"
mkdir -p "$OUT"
if [[ $DRY == 1 ]]; then
    BATCH=$([[ "${SCENE_BATCHES:-true}" == true ]] && echo 5 || echo 2)
    ARGS=(--device cpu --precision fp32 --max-steps 4 --batch-size "$BATCH" --set 'resolutions=[[64,96]]'
          --set num_workers=1 --set val_samples=2 --set val_every=4 --set parallax_samples=8)
else
    WORKERS=$(( $(nproc) > 2 ? $(nproc) - 2 : 1 ))
    BATCH=$([[ "${SCENE_BATCHES:-true}" == true ]] && echo 20 || echo 16)
    ARGS=(--device cuda --precision bf16 --max-steps "$STEPS" --batch-size "$BATCH"
          --set "num_workers=$WORKERS" --set val_every=200 --set save_every=100)
fi
ARGS+=(--set "window_guide=${GUIDE:-0}" --set "cvt_random_placement=${RANDOM_PLACEMENT:-false}"
       --set "cvt_train_shifts=${TRAIN_SHIFTS:-false}")
if [[ "${SCENE_BATCHES:-true}" == true ]]; then
    ARGS+=(--set synthetic_scene_batches=true --set synthetic_views_per_scene=5)
else
    ARGS+=(--set synthetic_scene_batches=false)
fi
RECIPE="${RECIPE:-configs/default-lite-synthetic-stage5.yaml}"
RESUME=()
if [[ -f "$RUN/checkpoints/last.state.pt" ]]; then RESUME=(--resume); fi
"$PY" -c "import torch; print('torch', torch.__version__, '|', torch.cuda.get_device_name() if torch.cuda.is_available() else 'no GPU')"
# The run saves every save_every steps; a stop by the time limit keeps the last saved checkpoint.
timeout --signal=INT "$SECONDS_LEFT" "$PY" -m mvsformerpp train "$RECIPE" -o "$RUN" \
    --checkpoint src/mvsformerpp/assets/weights/mvsformerpp-lite-synthetic.safetensors "${RESUME[@]}" "${ARGS[@]}" \
    || echo "training stopped (time limit or error, exit $?): exporting the last checkpoint"
"$PY" - "$RUN" "$OUT/weights" "$(basename "$RECIPE" .yaml)" <<'PYEOF'
import json, sys
from pathlib import Path
from mvsformerpp.models.checkpoint import load_model
from mvsformerpp.models.shipped import write_shipped
run, out = Path(sys.argv[1]), Path(sys.argv[2])
last = run / "checkpoints" / "last.safetensors"
if not last.is_file():
    sys.exit(f"no checkpoint in {run}: nothing to export")
rows = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines() if x.strip()]
steps = max((r["step"] for r in rows if "loss" in r), default=0)
path = write_shipped(load_model(last), "lite", out, "mvsformerpp-lite-synthetic.safetensors",
                     {"summary": f"{sys.argv[3]} on a GPU, {steps} steps", "steps": str(steps)})
print(f"exported {path} ({path.stat().st_size / 2**20:.1f} MiB) after {steps} steps")
PYEOF
cp "$RUN/metrics.jsonl" "$RUN/config.yaml" "$OUT/"
