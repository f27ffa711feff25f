"""Child-process environments that stand in for another x86 CPU (a plain helper module next to the tests).

Floating-point results can differ in their last bits from one CPU to another through three libraries that pick
their code by CPU:

- numba's machine code: LLVM compiles the kernels for the host (``NUMBA_CPU_NAME`` and ``NUMBA_CPU_FEATURES``
  choose another target; setting only the name keeps the host's features, AVX-512 included, so both are set);
- numpy's SIMD dispatch: on AVX-512 its float64 exp, log, log10, log1p, expm1, power, cbrt, arctan and sinh run
  other code than on AVX2 (``NPY_DISABLE_CPU_FEATURES`` switches the AVX-512 targets off);
- MKL (torch's matrix products): ``MKL_ENABLE_INSTRUCTIONS=AVX2`` (the package pins MKL's code path with
  ``MKL_CBWR=AVX2,STRICT``, so this one must not move anything; ``tests/test_reproducible.py``).

glibc's libm (which numba's kernels call for sin, exp, log, ...) picks its FMA variant on every x86 CPU with FMA and
AVX2, AVX-512 or not: nothing to emulate there.
"""

from __future__ import annotations

import os

# numpy 2.x's dispatch targets above AVX2 (X86_V3): switched off, numpy runs its AVX2 code
NUMPY_AVX2 = {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"}
MKL_AVX2 = {"MKL_ENABLE_INSTRUCTIONS": "AVX2"}
TORCH_AVX2 = {"ATEN_CPU_CAPABILITY": "avx2"}  # torch's own vectorised kernels (tanh, exp, ...)
OPENBLAS_AVX2 = {"OPENBLAS_CORETYPE": "Haswell"}  # numpy's and scipy's BLAS
# glibc's libm without its FMA code (an x86-64 CPU without FMA, or a virtual machine that hides it): its SSE2 code
# for sin, cos, exp, log, pow, atan, ... rounds differently in the last bit
LIBM_SSE2 = {"GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA"}
NUMBA_AVX2_CPU = "znver3"  # an AVX2 EPYC (Zen 3)


def numba_avx2(cache_dir: str) -> dict:
    """numba's target: this CPU without its AVX-512 features (the features of an AVX2 EPYC), compiled into its own
    cache folder ``cache_dir`` (numba would otherwise keep these kernels beside the host's)."""
    import llvmlite.binding as ll

    feats = ll.get_host_cpu_features()
    flags = ",".join(("-" if ("avx512" in k or k.startswith(("avx10", "amx", "evex"))) or not v else "+") + k
                     for k, v in sorted(feats.items()))
    return {"NUMBA_CPU_NAME": NUMBA_AVX2_CPU, "NUMBA_CPU_FEATURES": flags, "NUMBA_CACHE_DIR": cache_dir}


def paths(tmp: str) -> dict[str, dict]:
    """Name -> the environment changes of each emulated path ("native": a fresh process on this CPU; "avx2": all
    three libraries at once, an AVX2 machine). ``tmp``: a folder for numba's caches."""
    return {
        "native": {},
        "numba-avx2": numba_avx2(os.path.join(tmp, "numba-avx2")),
        "numpy-avx2": dict(NUMPY_AVX2),
        "mkl-avx2": dict(MKL_AVX2),
        "torch-avx2": dict(TORCH_AVX2),
        "openblas-avx2": dict(OPENBLAS_AVX2),
        "avx2": {**numba_avx2(os.path.join(tmp, "numba-avx2")), **NUMPY_AVX2, **MKL_AVX2, **TORCH_AVX2,
                 **OPENBLAS_AVX2},
        "libm-sse2": dict(LIBM_SSE2),
    }


def openblas_core() -> str | None:
    """The OpenBLAS kernel set ("core") that SciPy's BLAS runs on in this process, e.g. "SkylakeX" or "Haswell"; None
    where it cannot be read. OpenBLAS picks it from the CPU's model, not its features: OpenBLAS 0.3.30 runs its
    Haswell (AVX2) kernels on an AVX-512 AMD EPYC of family 26, so there its AVX2 path is the native one."""
    import ctypes
    import glob

    import scipy

    for lib in sorted(glob.glob(os.path.join(os.path.dirname(scipy.__file__), os.pardir, "scipy.libs", "*openblas*"))):
        try:
            corename = ctypes.CDLL(lib).scipy_openblas_get_corename
        except (OSError, AttributeError):
            continue
        corename.restype = ctypes.c_char_p
        return corename().decode()
    return None


def has_avx512() -> bool:
    """Whether this CPU has AVX-512 (on one without, every emulated path is the native one)."""
    import llvmlite.binding as ll

    return bool(ll.get_host_cpu_features().get("avx512f"))
