#!/usr/bin/env bash
# The GPU numbers in one run of a few minutes: the paper network at 1152x1536 with 5 views, fp32 and
# bf16, PyTorch SDPA and FlashAttention-2 (where flash_attn is installed), seconds per view and peak GPU
# memory next to the paper's 0.354 s and 5,964 MB on an RTX A6000, then reconstruct end to end on 8
# synthetic views per precision. Needs a CUDA build of torch in the environment (e.g.
# `make install TORCH_SPEC="torch==2.13.0 --index-url https://download.pytorch.org/whl/cu126"`).
#   bench/gpu.sh                 # writes bench/gpu_results.json
#   bench/gpu.sh --dry-run       # the same script on the CPU at 128x160 (checks that it works; JSON to /tmp)
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PY:-.venv/bin/python}"
if [[ " $* " == *" --dry-run "* ]]; then OUT="${OUT:-${TMPDIR:-/tmp}/gpu_dry_run.json}"; fi
OUT="${OUT:-bench/gpu_results.json}"
"$PY" -c "import torch; print('torch', torch.__version__, '| CUDA', torch.version.cuda, '|', \
torch.cuda.get_device_name() if torch.cuda.is_available() else 'no GPU')"
exec "$PY" bench/bench_gpu.py --json "$OUT" "$@"
