"""Where the core's time goes at steady state: a sampling profile (Linux perf) of ``cvt-sim run``'s
window, per compiled kernel and per library function, for the floor-ratio target of issue 12.

    cvt-sim bench profile [--scenes SCENE ...] [--span S] [--write FILE]

numba's kernels are machine code that perf cannot name by itself. A child process compiles them
afresh (a NUMBA_CACHE_DIR of its own, 2–4 min: a kernel loaded from the disk cache keeps no symbol
table) and writes ``/tmp/perf-PID.map``, perf's convention for JIT code, from the addresses numba's
code libraries give; perf then names every sample. Kernels the solver inlines (``inline_kernel``:
linkage, torques, dense output, guards) are counted in their caller. The child runs each scene as
the steady-state benchmark does (2 s from rest, then SPAN s with 0.1 s samples, streamed) under
``perf record -k CLOCK_MONOTONIC``, and reports each window's bounds on that clock so that only
the window's samples are counted (not the compilation's).
"""
import argparse
import gc
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

from .report import environment, replace_section, table
from .steady_state import SAMPLE_DT, SCENES, WARM  # the window as the steady-state benchmark's

TITLE = '## Where the time goes at steady state (profile)'
SPAN = 2000.0          # [s] simulated per scene: 2–10 s of wall time, ~10⁴ samples at FREQUENCY
FREQUENCY = 4999       # [Hz] perf's sampling rate
_REPORT_LINE = re.compile(r'^\s*([\d.]+)%\s+(\d+)\s+(.+?)\s+\[([.kg])\]\s+(.+?)\s*$')


class ProfileError(RuntimeError):
    """perf is missing or refused to record."""


# ------------------------------------------------------------------ the child: run and map
def perf_map_entries():
    """(address, size, symbol) of every function numba compiled in this process (not of kernels
    loaded from the disk cache: those carry no symbols), one per address; size = gap to the next
    function."""
    from numba.core.registry import CPUDispatcher
    entries = {}
    seen = set()
    for obj in gc.get_objects():
        if not isinstance(obj, CPUDispatcher):
            continue
        for cres in list(obj.overloads.values()):
            library = cres.library
            if id(library) in seen:
                continue
            seen.add(id(library))
            try:
                functions = [f.name for f in library._final_module.functions
                             if not f.is_declaration]
            except Exception:   # a library loaded from the cache has no module
                continue
            for name in functions:
                try:
                    address = library.get_pointer_to_function(name)
                except Exception:   # a name the JIT did not keep
                    continue
                if address:
                    entries[address] = name   # a callee linked into several libraries: once
    ordered = sorted(entries.items())
    return [(a, (ordered[i + 1][0] - a if i + 1 < len(ordered) else 4096), n)
            for i, (a, n) in enumerate(ordered)]


def write_perf_map(entries, pid=None):
    path = f'/tmp/perf-{pid or os.getpid()}.map'
    with open(path, 'w') as f:
        for address, size, name in entries:
            f.write(f'{address:x} {min(size, 1 << 20):x} {name}\n')
    return path


def child_main(scenes, span):
    """Compile, map, then run each scene's window; one JSON line per scene on stdout."""
    from ..scene import load_scene
    from ..solver import advance_layout as AL
    from ..solver.simulator import Simulator
    sims = {}
    for name in scenes:
        sim = Simulator(load_scene(name))
        sim.advance(WARM)
        sim.run(0.5, SAMPLE_DT, keep_samples=False)   # every kernel of the window compiled
        sims[name] = sim
    path = write_perf_map(perf_map_entries())
    gc.collect()
    gc.freeze()    # the compiler's heap: no collection of it inside a window
    for name, sim in sims.items():
        c0 = sim.counters.copy()
        t0 = time.clock_gettime(time.CLOCK_MONOTONIC)
        sim.run(span, SAMPLE_DT, keep_samples=False)
        t1 = time.clock_gettime(time.CLOCK_MONOTONIC)
        c = sim.counters - c0
        print(json.dumps({'scene': name, 'start': t0, 'stop': t1, 'span': span,
                          'rhs': int(c[AL.C_RHS]), 'steps': int(c[AL.C_STEPS]),
                          'map': path}), flush=True)
    return 0


# ------------------------------------------------------------------ the parent: record, report
def kernel_name(symbol):
    """'cvt_ros.solver.hybrid.advance' from numba's mangled name (None if it is not one);
    numba's Python wrappers ('cpython.', 'cfunc.') keep a prefix."""
    prefix = ''
    if symbol.startswith('cfunc.'):
        prefix, symbol = 'cfunc ', symbol[len('cfunc.'):]
    if not symbol.startswith('_ZN'):
        return None
    parts, i = [], 3
    while i < len(symbol) and symbol[i].isdigit():
        j = i
        while j < len(symbol) and symbol[j].isdigit():
            j += 1
        n = int(symbol[i:j])
        parts.append(symbol[j:j + n])
        i = j + n
    if not parts:
        return None
    if parts[0] == 'cpython':
        prefix, parts = 'cpython ', parts[1:]
    return prefix + '.'.join(parts)


def label(dso, symbol):
    """What a perf report row is, in the project's terms."""
    name = kernel_name(symbol)
    if name is not None:
        return name
    if 'libm' in dso:
        return f'libm {symbol.split("_fma")[0].lstrip("_")}'
    if dso.startswith('[kernel') or dso == '[unknown]':
        return 'operating system (page faults, system calls, interrupts)'
    if 'libpython' in dso or dso.startswith('python'):
        return 'Python interpreter (libpython)'
    if '_multiarray_umath' in dso:
        return 'numpy'
    return f'{os.path.basename(dso)} {symbol}'


def parse_report(text):
    """{label: samples} from ``perf report --stdio -n --sort dso,sym`` output."""
    counts = {}
    for line in text.splitlines():
        m = _REPORT_LINE.match(line)
        if not m or line.lstrip().startswith('#'):
            continue
        _, samples, dso, _, symbol = m.groups()
        key = label(dso.strip(), symbol)
        counts[key] = counts.get(key, 0) + int(samples)
    return counts


def record(scenes, span, log):
    """Run the child under perf; returns [(window, {label: samples})] per scene."""
    perf = shutil.which('perf')
    if perf is None:
        raise ProfileError('needs Linux perf on PATH (Debian: apt install linux-perf)')
    with tempfile.TemporaryDirectory(prefix='cvt_profile_') as tmp:
        data = os.path.join(tmp, 'perf.data')
        env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(tmp, 'numba'))
        cmd = [perf, 'record', '-F', str(FREQUENCY), '-k', 'CLOCK_MONOTONIC', '-o', data, '--',
               sys.executable, '-m', 'cvt_ros.bench.profile', '--child', str(span), *scenes]
        log(f"compiling the kernels afresh and running {', '.join(scenes)} under perf "
            f"(3–5 min)")
        run = subprocess.run(cmd, env=env, capture_output=True, text=True)
        windows = [json.loads(ln) for ln in run.stdout.splitlines() if ln.startswith('{')]
        if run.returncode != 0 or len(windows) != len(scenes):
            raise ProfileError(f'perf record failed (exit {run.returncode}): '
                               f'{run.stderr.strip()[-800:]}')
        results = []
        for w in windows:
            report = subprocess.run(
                [perf, 'report', '-i', data, '--stdio', '--no-children', '-n',
                 '--sort', 'dso,sym', '--time', f"{w['start']:.6f},{w['stop']:.6f}"],
                capture_output=True, text=True)
            if report.returncode != 0:
                raise ProfileError(f'perf report failed: {report.stderr.strip()[-800:]}')
            results.append((w, parse_report(report.stdout)))
        try:
            os.remove(windows[0]['map'])   # one map, written by the child for all its windows
        except OSError:
            pass
    return results


TOP_SHARE, TOP_ROWS = 0.02, 10   # the rows shown: ≥ 2 % of some scene's window, at most 10


def section(results, command, load):
    """One table: the pieces that take ≥ 2 % of some scene's window (at most 10), a column per
    scene, the rest summed in the last row."""
    env = environment()
    L = [TITLE, '']
    L += [f"`{command}` at {env['revision']}, {env['date']}; {env['cpu']}, {env['cores']} "
          f"cores, numba {env['versions']['numba']}; load average {load}. Linux perf samples "
          "each scene's steady-state window (as Speed at steady state runs it: 2 s from rest, "
          f"then the span with 0.1 s samples streamed) at {FREQUENCY} Hz; a kernel's share "
          "includes what LLVM inlined into it; `libm` rows are the elementary functions the "
          "kernels call (sincos: the crank angle and the open output's modal rotation; pow: "
          "the step-size controller).", '']
    totals = [sum(counts.values()) or 1 for _, counts in results]
    shares = {}
    for (_, counts), total in zip(results, totals, strict=True):
        for key, n in counts.items():
            shares.setdefault(key, []).append(n / total)
    top = sorted((k for k, v in shares.items() if max(v) >= TOP_SHARE),
                 key=lambda k: -max(shares[k]))[:TOP_ROWS]
    rows = []
    for key in top:
        rows.append([f'`{key}`'] + [f'{100 * n / total:.1f} %' for (w, counts), total
                                    in zip(results, totals, strict=True)
                                    for n in [counts.get(key, 0)]])
    rest = [1.0 - sum(counts.get(k, 0) for k in top) / total
            for (w, counts), total in zip(results, totals, strict=True)]
    rows.append(['(the rest)'] + [f'{100 * r:.1f} %' for r in rest])
    windows = [w for w, _ in results]
    rows.append(['µs per simulated second (wall)'] + [
        f"{1e6 * (w['stop'] - w['start']) / w['span']:.0f}" for w in windows])
    rows.append(['simulated [s]; right-hand sides; steps; perf samples'] + [
        f"{w['span']:g}; {w['rhs']}; {w['steps']}; {n}" for w, n in zip(windows, totals,
                                                                         strict=True)])
    L += table(['where (share of the window)'] + [w['scene'] for w in windows], rows)
    return '\n'.join(L + [''])


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == '--child':
        return child_main(argv[2:], float(argv[1]))
    ap = argparse.ArgumentParser(prog='cvt-sim bench profile',
                                 description=__doc__.split('\n\n')[0],
                                 epilog='Needs Linux perf (Debian: linux-perf) and a kernel that '
                                        'lets a user sample their own processes '
                                        '(kernel.perf_event_paranoid ≤ 2).')
    ap.add_argument('--scenes', nargs='+', default=list(SCENES), metavar='SCENE',
                    help=f"scenes (default {' '.join(SCENES)})")
    ap.add_argument('--span', type=float, default=SPAN,
                    help='simulated seconds per scene in the window (default %(default)g)')
    ap.add_argument('--write', metavar='FILE',
                    help=f'put the section "{TITLE[3:]}" into FILE (e.g. BENCHMARKS.md)')
    a = ap.parse_args(argv)
    if not a.span > 0.0:
        ap.error(f'--span must be > 0 s (got {a.span})')
    from ..scene import load_scene
    for name in a.scenes:
        try:
            load_scene(name)
        except (OSError, ValueError) as e:
            ap.error(str(e))
    load0 = os.getloadavg()[0]
    try:
        results = record(a.scenes, a.span, lambda m: print(f'profile: {m}', file=sys.stderr))
    except ProfileError as e:
        print(f'cvt-sim bench profile: {e}', file=sys.stderr)
        return 2
    text = section(results, 'cvt-sim bench profile ' + ' '.join(argv),
                   f"{load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end")
    print(text)
    if a.write:
        replace_section(a.write, TITLE, text)
        print(f'written to {a.write} (section {TITLE[3:]!r})', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
