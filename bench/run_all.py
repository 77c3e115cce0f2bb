"""Run every benchmark with its quick settings, one after another."""

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).parent
RUNS = [
    ["bench_model.py", "--sizes", "512x640", "1152x1536"],
    ["bench_fusion.py", "--scale", "0.25"],
    ["bench_eval.py"],
    ["bench_cache.py"],
    ["bench_precision.py"],
    ["bench_lite.py", "--rounds", "1"],
    ["bench_data.py", "--samples", "5"],
    ["bench_onnx.py", "--cases", "lite:480x640", "paper:512x640", "--rounds", "1"],
    ["onnx_parity.py"],
]

for args in RUNS:
    print(f"\n=== {' '.join(args)}", flush=True)
    subprocess.run([sys.executable, str(HERE / args[0]), *args[1:]], check=True)
