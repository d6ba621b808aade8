"""What produced a result: package versions and the machine, recorded next to every checkpoint."""

from __future__ import annotations

import os
import platform
from importlib import metadata
from pathlib import Path

PACKAGES = ("torch", "stable-baselines3", "sb3-contrib", "gymnasium", "mujoco", "ale-py", "numpy", "masksembles",
            "scikit-learn", "paper_lib")


def package_versions() -> dict[str, str]:
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    versions["python"] = platform.python_version()
    return versions


def machine() -> dict[str, str]:
    """The platform and the CPU: its model and SIMD extensions choose the BLAS and torch kernels, so two machines that
    differ there can give results that differ in the last float bits (`python -m paper_lib.pipeline.verify` shows where)."""
    cpu = cpu_info()
    return {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpu": cpu.get("model name", "unknown"), "cpus": str(os.cpu_count()),
            "simd": " ".join(sorted(f for f in cpu.get("flags", "").split() if f.startswith(("avx", "amx", "fma"))))}


def cpu_info(path: str | Path = "/proc/cpuinfo") -> dict[str, str]:
    """The first processor's fields in /proc/cpuinfo (Linux); empty where there is no such file."""
    try:
        text = Path(path).read_text()
    except OSError:
        return {}
    fields = {}
    for line in text.split("\n\n")[0].splitlines():
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    return fields


def file_digest(path: str | Path) -> str:
    """The SHA-256 of a file's bytes: a result made from a checkpoint records it, so a reader can refuse a result
    whose checkpoint has since changed (or that was copied from another run)."""
    import hashlib

    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
