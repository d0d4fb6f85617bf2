"""The machine an absolute figure was measured on: CPU, CPU count, numpy's BLAS, numba."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def machine() -> str:
    """``AMD EPYC, 2 CPUs, numpy 2.4.6, BLAS openblas Haswell, numba 0.68.1`` — every
    absolute figure needs it."""
    from importlib.metadata import version

    import numpy  # loads the BLAS that threadpoolctl reports
    from threadpoolctl import threadpool_info

    cpu = platform.machine()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        names = [
            line.split(":", 1)[1].strip()
            for line in cpuinfo.read_text().splitlines()
            if line.startswith("model name")
        ]
        cpu = names[0] if names else cpu
    blas = ", ".join(
        sorted(
            {
                f"{pool.get('internal_api')} {pool.get('architecture', '')}".strip()
                for pool in threadpool_info()
                if pool.get("user_api") == "blas"
            }
        )
    )
    return (
        f"{cpu}, {os.cpu_count()} CPUs, numpy {numpy.__version__}, BLAS {blas or 'unknown'}, "
        f"numba {version('numba')}"
    )
