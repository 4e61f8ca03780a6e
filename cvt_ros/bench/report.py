"""The markdown report: number formats, tables, the machine it ran on, and BENCHMARKS.md
written so that the sections of other benchmarks (ROS node, recording, …) are kept as they are."""
import datetime
import math
import os
import platform
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


# sections this module writes into BENCHMARKS.md; every other section there is kept
OWN_TITLE = '# Benchmarks'


OWN_SECTIONS = ('Speed at steady state', 'Scaling', 'Clutch switches at every tolerance',
                'Default settings', 'Work-precision',
                'Speed-up at equal error', 'Numerical stability on hard cases',
                'Stability limit of fixed-step RK4', 'Long run', 'Known defects')


def fmt(x, digits=3):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return 'nan'
    if isinstance(x, int):
        return str(x)
    if x == 0.0:
        return '0'
    return f'{x:.{digits}g}' if 1e-3 <= abs(x) < 1e5 else f'{x:.{digits - 1}e}'


def cpu_model():
    """The CPU's model name from /proc/cpuinfo ('' where there is none)."""
    try:
        return next((line.split(':', 1)[1].strip() for line in
                     Path('/proc/cpuinfo').read_text().splitlines()
                     if line.startswith('model name')), '')
    except OSError:
        return ''


def revision_and_date():
    """(`git describe --always --dirty` of this checkout or 'unknown', the UTC time now)."""
    try:
        rev = subprocess.run(['git', 'describe', '--always', '--dirty'], cwd=ROOT, text=True,
                             capture_output=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        rev = ''
    return rev or 'unknown', datetime.datetime.now(datetime.UTC).strftime('%Y-%m-%d %H:%M UTC')


def environment():
    cpu = cpu_model() or platform.processor()
    versions = {}
    for mod in ('numpy', 'scipy', 'numba', 'matplotlib'):
        try:
            versions[mod] = __import__(mod).__version__
        except ImportError:
            versions[mod] = 'absent'
    rev, date = revision_and_date()
    return {'cpu': cpu or 'unknown', 'cores': os.cpu_count(), 'python': platform.python_version(),
            'platform': platform.platform(), 'versions': versions, 'revision': rev,
            'date': date, 'load': os.getloadavg()}


def table(header, rows):
    """Markdown table; a '|' inside a cell is escaped."""
    def line(cells):
        return '| ' + ' | '.join(str(c).replace('|', '\\|') for c in cells) + ' |'
    return [line(header), '|' + '---|' * len(header)] + [line(r) for r in rows]


def _blocks(text):
    """Split markdown into (heading, text) blocks at '# ' / '## ' headings outside code fences."""
    blocks = []
    head, lines = None, []
    fence = False
    for line in text.splitlines(keepends=True):
        if line.lstrip().startswith(('```', '~~~')):
            fence = not fence
        if not fence and re.match(r'#{1,2} ', line):
            if head is not None or ''.join(lines).strip():
                blocks.append((head, ''.join(lines)))
            head, lines = line.strip(), [line]
            continue
        lines.append(line)
    if head is not None or ''.join(lines).strip():
        blocks.append((head, ''.join(lines)))
    return blocks


def _own(head):
    if head is None or head == OWN_TITLE:
        return True
    title = head.lstrip('#').strip()
    return head.startswith('## ') and title.startswith(OWN_SECTIONS)


def _key(head):
    """The name a section is known by across runs: its OWN_SECTIONS prefix (a heading may
    carry the run's span, 'Long run (1 h simulated)'), else the heading itself."""
    title = (head or '').lstrip('#').strip()
    return next((name for name in OWN_SECTIONS if title.startswith(name)), head)


def write_report(path, text, keep_others=True):
    """Write the report ``text`` (a title block, then sections). ``keep_others`` with an
    existing file: each section of ``text`` replaces the section of the same name where it
    stands, a new one goes after the section ``text`` has before it, and everything else is
    kept as it is: the file's own title block (BENCHMARKS.md's summary), the sections this
    run did not make (a ``--sections`` subset) and those of other benchmarks."""
    path = Path(path)
    if not (keep_others and path.exists()):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text if text.endswith('\n') else text + '\n')
        return
    new = [(_key(h), body) for h, body in _blocks(text) if h is not None and h.startswith('## ')]
    old = _blocks(path.read_text())
    present = {_key(h) for h, _ in old}
    after = {}                       # a section not in the file → after its predecessor
    previous = None
    for key, body in new:
        if key not in present:
            after.setdefault(previous, []).append(body)
        else:
            previous = key
    replaced = dict(new)
    out = []
    for k, (head, body) in enumerate(old):
        key = _key(head)
        if key in replaced:
            out.append(replaced[key])
        else:
            out.append(body)
        if k == 0 and None in after:     # sections before any the file has: after its title
            out += after.pop(None)
        if key in after:
            out += after.pop(key)
    for bodies in after.values():
        out += bodies
    path.write_text(''.join(b if b.endswith('\n\n') else b.rstrip('\n') + '\n\n'
                            for b in out).rstrip() + '\n')


def stamp(command, env, load):
    """One line under a section's heading: how, where and when it was made. ``load``: (load
    average at the start, at the end) of the part that made the section."""
    versions = ', '.join(f'{k} {v}' for k, v in env['versions'].items() if k != 'matplotlib')
    return (f"`{command}` at {env['revision']}, {env['date']}; {env['cpu']}, {env['cores']} "
            f"cores, Python {env['python']}, {versions}; load average {load[0]:.2f} → "
            f"{load[1]:.2f}.")


def publish(text, out, title, log):
    """Print a benchmark's section and put it into the markdown file ``out`` (None or '-':
    print only) in place of the section ``title``; the exit code 0."""
    print(text)
    if out and out != '-':
        replace_section(out, title, text)
        log(f"wrote the section to {out}")
    return 0


def replace_section(path, title, text):
    """Put ``text`` (a section, its ``title`` heading first) into the markdown file ``path`` in
    place of the section of that title, or at its end; every other section is kept as it is."""
    path = Path(path)
    blocks = _blocks(path.read_text()) if path.exists() else []
    out, done = [], False
    for head, body in blocks:
        if head == title:
            out.append(text.rstrip() + '\n\n')
            done = True
        else:
            out.append(body)
    if not done:
        out.append(('\n' if out and not out[-1].endswith('\n\n') else '') + text)
    path.write_text(''.join(out).rstrip() + '\n')
