"""Monocular whole-body motion recognition and recovery, and the MuJoCo harness that measures it.

Subpackages follow the data flow: ``body`` (the humanoid and its kinematics), ``motion`` (captured and
procedural primitives), ``scene`` (markers, camera, occluders, observations), ``engine`` (the method),
``evaluation`` (scenarios, runner, metrics, reports).
"""

import hashlib
import os
from pathlib import Path

# Offscreen rendering must pick its GL back-end before mujoco is first imported; EGL renders on the CPU
# through Mesa when there is no GPU. A user's own setting wins.
os.environ.setdefault("MUJOCO_GL", "egl")


def _full_vector_width() -> None:
    """Compile numba's kernels for the CPU's full vector registers. LLVM's tuning for recent Intel cores
    prefers 256-bit vectors even where the CPU has 512-bit ones; the engine's flow likelihood is arithmetic on
    contiguous doubles, measured 14% faster with 512-bit ones (docs/log/2026-12-05-speed-step-07.md). It must be set before
    numba is first imported; a user's own ``NUMBA_CPU_FEATURES`` wins, and CPUs without AVX-512 are left as
    they are."""
    if "NUMBA_CPU_FEATURES" in os.environ:
        return
    import llvmlite.binding as llvm

    features = llvm.get_host_cpu_features().flatten()
    if "+avx512f" in features.split(","):
        os.environ["NUMBA_CPU_FEATURES"] = features + ",-prefer-256-bit"


_full_vector_width()


def kernel_cache_dir(package: Path) -> Path:
    """Where numba keeps the compiled kernels of the sources under ``package``: a directory per version of the
    files that compile kernels (those that mention numba). numba checks only a kernel's own file, so a kernel
    that inlines another file's function (``engine/vector_math.py``) would otherwise keep its old code after an
    edit there, and give results the code no longer computes."""
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        text = path.read_bytes()
        if b"numba" in text:
            digest.update(path.relative_to(package).as_posix().encode() + b"\0" + text + b"\0")
    return package / "__pycache__" / "numba" / digest.hexdigest()[:12]


# A user's own NUMBA_CACHE_DIR wins; it must be set before numba is first imported.
os.environ.setdefault("NUMBA_CACHE_DIR", str(kernel_cache_dir(Path(__file__).resolve().parent)))

__version__ = "0.1.0"
