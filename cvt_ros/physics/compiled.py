"""The decorators every compiled kernel uses (numba, cached on disk).

error_model='numpy': a division by zero gives inf/nan (caught by the solver's finiteness check)
instead of a Python exception check on every division. fastmath flags that keep IEEE nan/inf
semantics ('nnan' and 'ninf' are left out, so isfinite checks stay meaningful) and keep the order
of additions ('reassoc' is left out): with reassociation allowed, the same kernel compiled in one
process and loaded from the disk cache in another gave results that differ in the 11th digit
(conveyor, rk4: 8e-11 in φ4 after 46 ms), which broke "the device's lockstep run equals the
offline core's, to the bit" whenever the two processes had not compiled alike. Without it they
agree to the bit whichever process compiled (test_compiled_alike.py), for ~3 % of speed. A
second way the two differed (the N-path core, 8e-13 after 1 ms): a caller's call to a
non-inlined kernel bound to whichever copy of the callee the JIT had loaded first, the callee's
own in the process that compiled, the caller's in the one that loaded the cache. Every compiled
object now calls its own copies (``_bind_callees_locally``).

The rule for every kernel of the package (physics/, solver/, and any room that compiles): use
these decorators, not numba's ``inline='always'`` (a bare ``njit`` only for an entry point called
from Python that needs other flags: drives.plan_into's strict IEEE, solver/period.py's).

* ``kernel``: compiled once and called. The default.
* ``inline_kernel``: compiled once, then inlined by LLVM at every call site (``forceinline``:
  LLVM's alwaysinline), for the small functions the solver calls many times per step (linkage,
  torques, dense output, guards), where a call that passes half a dozen arrays costs more than
  the work (the rocker speed: 55 ns called, 20 ns inlined). Not numba's ``inline='always'``,
  which copies the callee's IR into each call site and types and lowers it there again,
  inlines of inlines multiplied: at c1dbe6f a third of ``cvt-sim warmup`` went into copying
  IR alone; LLVM's inlining costs a fraction of that (BENCHMARKS.md, Compile time).
* Both are compiled once per set of argument *types*: a kernel called with a constant
  (``take_step(DOPRI5, FULL, …)``, ``locate_root(True, …)``) is typed with the constant's type,
  not with its value (numba's default compiles one specialization per literal value: 2–4 of
  the biggest kernels). A path that a constant selects is a runtime branch, predicted well.
  (``OneSignature``; test_compiled_alike.py checks that no kernel has two signatures.)

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
from numba.core import types
from numba.core.codegen import CPUCodeLibrary
from numba.core.registry import CPUDispatcher

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


def _bind_callees_locally(finalize_final_module):
    """Wrap numba's last step before machine code so that a kernel's object code calls its own
    copies of the kernels it calls, not whichever copy the JIT's linker saw first.

    numba links every callee's optimized IR into its caller's module as ``linkonce_odr`` (weak in
    the object code), and the JIT binds a weak symbol to the first definition it loaded. A process
    that compiles fresh compiles (and loads) the callees first, so a caller's call to a non-inlined
    ``kernel`` ran the callee's own library; a process that loads the caller from the disk cache
    loads the caller's object first and ran the copy inside it. The two copies are the same IR
    optimized again inside different modules and need not agree to the bit (the N-path core:
    8e-13 after 1 ms of conveyor_4path). Here the module that becomes machine code gets those
    copies as ``internal`` (after optimization, so the code is unchanged), while the module other
    callers link keeps numba's ``linkonce_odr``: every object is self-contained and runs the same
    code whether it was compiled in this process or loaded from the cache."""
    def finalize_bound_locally(self):
        module = self._final_module
        if self._shared_module is None and any(not f.is_declaration for f in module.functions):
            shared = module.clone()        # what numba's _get_module_for_linking would make
            for f in shared.functions:
                if not f.is_declaration and f.linkage.name == 'external':
                    f.linkage = 'linkonce_odr'
            self._shared_module = shared
            for f in module.functions:
                if not f.is_declaration and f.linkage.name == 'linkonce_odr':
                    f.linkage = 'internal'
        finalize_bound_locally.original(self)
    finalize_bound_locally.original = finalize_final_module
    return finalize_bound_locally


# (numba internals, checked on the pinned numba; another numba without this step runs as numba
# links, bit-identical only among processes that share how their kernels were loaded)
_FINALIZE = getattr(CPUCodeLibrary, '_finalize_final_module', None)
if _FINALIZE is not None and not hasattr(_FINALIZE, 'original'):
    CPUCodeLibrary._finalize_final_module = _bind_callees_locally(_FINALIZE)


class OneSignature(CPUDispatcher):
    """A dispatcher that types a call from compiled code by its arguments' types, never by the
    values of constant ones (numba's literal types): one compiled version per signature."""

    def get_call_template(self, args, kws):
        return super().get_call_template(tuple(types.unliteral(a) for a in args),
                                         {k: types.unliteral(v) for k, v in kws.items()})


def _one_signature(dispatcher):
    dispatcher.__class__ = OneSignature
    return dispatcher


def kernel(func):
    return _one_signature(njit(cache=True, error_model='numpy', fastmath=FASTMATH,
                               forceinline=False, _nrt=False)(func))


def inline_kernel(func):
    return _one_signature(njit(cache=True, error_model='numpy', fastmath=FASTMATH,
                               forceinline=True, _nrt=False)(func))


def allocating_kernel(func):
    return _one_signature(njit(cache=True, error_model='numpy', fastmath=FASTMATH,
                               forceinline=False)(func))
