"""numba's `njit` when numba is installed (the `sitl` extra), else a no-op decorator.

Without numba the kernels run as plain Python floats: correct, only slower.
"""

try:  # pragma: no cover - depends on the environment
    from numba import njit as _njit

    def njit(fn):
        return _njit(cache=True, fastmath=False)(fn)

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    def njit(fn):
        return fn

    HAVE_NUMBA = False
