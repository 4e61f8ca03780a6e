"""The decorators every compiled kernel uses (numba, cached on disk).

error_model='numpy': a division by zero gives inf/nan (caught by the solver's finiteness check)
instead of a Python exception check on every division. fastmath flags that keep IEEE nan/inf
semantics ('nnan' and 'ninf' are left out, so isfinite checks stay meaningful) and keep the order
of additions ('reassoc' is left out): with reassociation allowed, the same kernel compiled in one
process and loaded from the disk cache in another gave results that differ in the 11th digit
(conveyor, rk4: 8e-11 in φ4 after 46 ms), which broke "the device's lockstep run equals the
offline core's, to the bit" whenever the two processes had not compiled alike. Without it they
agree to the bit whichever process compiled (test_compiled_alike.py), for ~3 % of speed.

``kernel`` for functions the solver calls a few times per step; ``inline_kernel`` for the small
ones it calls many times per step (linkage, torques, dense output, guards): numba inlines those
into their callers, which removes a call with half a dozen array arguments each time (measured
on the paper scene: 55 ns → 20 ns for the rocker speed).

No reference counting: numba's runtime (NRT) increments and decrements an atomic count on every
array view a kernel makes or passes on (a locked instruction, ~20 cycles each, hundreds per
control period): measured on the conveyor's 1 ms period, 25 % of the compiled time went there.
The kernels allocate nothing (the solver's working arrays come from the Simulator's scratch
block, solver/simulator.py), so they are compiled without NRT (``_nrt=False``): 4.2 → 3.0 µs a
period. ``allocating_kernel`` keeps NRT for the few that make arrays (the averaged model's,
which no NRT-free kernel calls: numba compiles a callee under its caller's flags).

numba keys a kernel's disk cache on the kernel's own source file only, so a cached solver kernel
that inlined physics code would outlive a change to that code: ``drop_stale_caches`` (run when
this module is first imported) deletes the package's cached kernels that are older than the
newest physics/ or solver/ source.
"""
import glob
import os

from numba import njit

FASTMATH = {'nsz', 'arcp', 'contract', 'afn'}
_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_KERNEL_SOURCES = ('physics', 'solver')
_CACHED_KERNELS = ('physics', 'solver', 'bench')   # rooms whose modules hold kernels


def drop_stale_caches():
    """Delete cached kernels (``__pycache__/*.nbi|nbc``) older than the newest kernel source."""
    sources = [p for room in _KERNEL_SOURCES
               for p in glob.glob(os.path.join(_PACKAGE, room, '*.py'))]
    try:
        newest = max(os.path.getmtime(p) for p in sources)
    except (OSError, ValueError):
        return
    for room in _CACHED_KERNELS:
        for path in glob.glob(os.path.join(_PACKAGE, room, '__pycache__', '*.nb[ic]')):
            try:
                if os.path.getmtime(path) < newest:
                    os.remove(path)
            except OSError:   # another process removed or rewrote it meanwhile
                pass


drop_stale_caches()


def kernel(func):
    return njit(cache=True, error_model='numpy', fastmath=FASTMATH, _nrt=False)(func)


def inline_kernel(func):
    return njit(cache=True, error_model='numpy', fastmath=FASTMATH, inline='always',
                _nrt=False)(func)


def allocating_kernel(func):
    return njit(cache=True, error_model='numpy', fastmath=FASTMATH)(func)
