"""The allocator tuning keeps freed tensor memory for reuse (far fewer page faults), on glibc."""

import subprocess
import sys

import pytest

# One torch thread: every allocation then goes through glibc's main arena. With several threads the
# per-thread arenas trim differently depending on how the work is spread, and the default allocator's
# fault count varied from 0 to ~10,000 between runs on the same machine. The input is large enough for the
# decoder's temporaries (50 MB) to exceed glibc's largest dynamic mmap threshold (32 MiB), so the default
# allocator maps and unmaps them on every pass instead of sometimes keeping them in the heap.
SCRIPT = r"""
import resource, sys, torch
torch.set_num_threads(1)
from mvsformerpp.utils.allocator import tune_allocator
if sys.argv[1] == "tuned":
    assert tune_allocator()
from mvsformerpp.models import prepared
from mvsformerpp.models.fpn import FPNDecoder, FPNEncoder
enc, dec = FPNEncoder(), FPNDecoder()
net = prepared.prepare(torch.nn.ModuleList([enc, dec]))
x = torch.randn(1, 3, 768, 1024)
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
counts = []
with torch.no_grad(), prepared.session(net):
    for _ in range(4):
        before = faults()
        dec(*enc(x))
        counts.append(faults() - before)
print(min(counts[1:]))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc tuning")
def test_tuned_allocator_reuses_freed_tensor_memory():
    def steady_state_faults(mode):
        out = subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, check=True)
        return int(out.stdout.strip().splitlines()[-1])

    default, tuned = steady_state_faults("default"), steady_state_faults("tuned")
    assert default > 1000  # each pass faults fresh pages in for its large temporaries
    assert tuned * 3 < default, (default, tuned)
