"""Process-wide tuning of glibc's malloc for large-tensor CPU inference.

PyTorch's CPU tensors come straight from ``malloc``. glibc serves blocks above its mmap threshold with
fresh ``mmap`` calls and returns them on ``free``, and trims the heap top eagerly, so a network that
allocates and frees hundreds of megabyte-sized temporaries per forward touches fresh pages again and
again: at 1152x1536 that is millions of page faults and several seconds of kernel time per forward.
Serving every block from the heap and keeping freed memory for reuse removes almost all of them; the
price is that the process keeps its peak memory until it exits, which suits a command that runs the
same forward view after view. The ``mvsformerpp`` command applies it at start; library users may call
:func:`tune_allocator` themselves (or set ``MALLOC_MMAP_MAX_=0 MALLOC_TRIM_THRESHOLD_=2000000000``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

# mallopt parameters (glibc malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4


def tune_allocator() -> bool:
    """Keep freed memory for reuse instead of returning it to the OS. True where it took effect
    (glibc); elsewhere nothing changes. Environment settings of the same knobs are left alone."""
    if not sys.platform.startswith("linux") or any(k in os.environ for k in ("MALLOC_MMAP_MAX_",
                                                                              "MALLOC_TRIM_THRESHOLD_")):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl, macOS)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, 2**31 - 1))
