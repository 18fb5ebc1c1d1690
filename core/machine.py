"""The machine a measurement ran on, as every record names it."""
from __future__ import annotations

import os
import platform
from pathlib import Path

#: the widest vector extension first: Dr.Jit's LLVM backend and OIDN both use the widest the CPU has,
#: so two machines of one model name may differ twofold in a kernel's speed
VECTOR_EXTENSIONS = (("avx512f", "AVX-512"), ("avx2", "AVX2"), ("avx", "AVX"), ("sse4_2", "SSE4.2"))


def cpu_description(cpuinfo: str) -> str:
    """The CPU's model name, family and model, and its widest vector extension,
    from the text of Linux's ``/proc/cpuinfo`` (the first processor's lines)."""
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        if not line.strip():
            if fields:
                break
            continue
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    name = fields.get("model name") or platform.processor() or platform.machine()
    if "cpu family" in fields and "model" in fields:
        name += f" (family {fields['cpu family']}, model {fields['model']})"
    flags = set(fields.get("flags", "").split())
    widest = next((label for flag, label in VECTOR_EXTENSIONS if flag in flags), None)
    return f"{name}, {widest}" if widest else name


def machine() -> str:
    """CPU (:func:`cpu_description`), cores, OS and Python, for the record of a measurement."""
    try:
        cpu = cpu_description(Path("/proc/cpuinfo").read_text())
    except OSError:
        cpu = platform.processor() or platform.machine()
    return (f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, "
            f"Python {platform.python_version()}")
