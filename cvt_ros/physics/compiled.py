"""The one decorator every compiled kernel uses (numba, cached on disk).

error_model='numpy': a division by zero gives inf/nan (caught by the solver's finiteness check)
instead of a Python exception check on every division. fastmath flags that keep IEEE nan/inf
semantics ('nnan' and 'ninf' are left out, so isfinite checks stay meaningful).
"""
from numba import njit

FASTMATH = {'nsz', 'arcp', 'contract', 'afn', 'reassoc'}


def kernel(func):
    return njit(cache=True, error_model='numpy', fastmath=FASTMATH)(func)
