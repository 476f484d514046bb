"""numba's `njit` when numba is installed (the `fast` or `sitl` extra), else a no-op decorator.

Without numba the SITL's kernels run as plain Python floats (correct, only slower) and the table lookup
keeps its numpy path (`contracts.lookup`). `fastmath=False`: IEEE arithmetic in the order written, so a
compiled kernel gives the same bits as its Python source.

A process that may not map executable memory (the service unit's `MemoryDenyWriteExecute=yes`, SELinux)
cannot JIT: numba's import then raises PermissionError (checked under PR_SET_MDWE,
tests/test_lookup_kernel.py), and this module falls back as if numba were absent, never failing the import.
"""

try:  # pragma: no cover - depends on the environment
    from numba import config as _config
    from numba import njit as _njit

    if _config.DISABLE_JIT:  # NUMBA_DISABLE_JIT=1: njit would hand back the Python source, slower than numpy
        raise ImportError("numba's JIT is disabled")

    def njit(fn):
        return _njit(cache=True, fastmath=False)(fn)

    HAVE_NUMBA = True
except (ImportError, OSError):  # pragma: no cover - no numba, or no executable memory for its JIT
    def njit(fn):
        return fn

    HAVE_NUMBA = False
