"""How much memory an all-pairs run needs, and whether the device has it."""

from __future__ import annotations

import os

import numpy as np
import warp as wp

from ...kernels.lanes import SCALARS, lane_width
from .engine import ENGINES

__all__ = ["memory_estimate", "check_memory", "available_memory"]


def available_memory(device):
    """Bytes available on the device (MemAvailable of /proc/meminfo for the CPU)."""
    if device.is_cuda:
        return int(device.free_memory)
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")


def memory_estimate(n, m, dtype="float64", device="cpu", engine="consensus"):
    """(device bytes, host bytes) needed by :func:`all_pairs` for n vertices and m triangles with ``engine``:
    the engine's state (``ENGINES[engine].array_bytes``, in n x (n padded to the lane width) numbers), and on
    the host the float64 (n, n) result, in the solver's precision the U of the last change test and the
    change test's difference (and, on a GPU, the copy of one state array at a time to the host;
    checkpoints write the state from views, not copies, on the CPU).
    """
    W = lane_width(SCALARS[dtype], n)
    cols = -(-n // W) * W
    size = np.dtype(dtype).itemsize
    device_bytes, engine_host = ENGINES[engine].array_bytes(n, m, size, cols)
    return device_bytes, 8 * n * n + size * n * cols * (3 if wp.get_device(device).is_cuda else 2) + engine_host


def check_memory(n, m, dtype, dev, engine="consensus"):
    """The footprint (bytes) of an all-pairs run; ValueError when it exceeds the available memory."""
    device_bytes, host_bytes = memory_estimate(n, m, dtype, dev, engine)
    if dev.is_cuda:
        cpu_available = available_memory(wp.get_device("cpu"))
        if device_bytes > available_memory(dev) or host_bytes > cpu_available:
            raise ValueError(f"expected enough memory for {n} vertices in {dtype}: needs {device_bytes / 1e9:.2f} GB "
                             f"on {dev} and {host_bytes / 1e9:.2f} GB on the host, got {available_memory(dev) / 1e9:.2f} "
                             f"GB and {cpu_available / 1e9:.2f} GB available")
    else:
        available = available_memory(dev)
        if device_bytes + host_bytes > available:
            raise ValueError(f"expected enough memory for {n} vertices in {dtype}: needs "
                             f"{(device_bytes + host_bytes) / 1e9:.2f} GB, got {available / 1e9:.2f} GB available"
                             + (" (float32 halves it)" if dtype == "float64" else ""))
    return device_bytes + host_bytes
