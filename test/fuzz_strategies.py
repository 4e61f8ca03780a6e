"""What the fuzz tests draw: hostile number texts, mutated file bytes, YAML flow text with any
leaf, and the bookkeeping they share (a folder's files before and after a command, the counts a
campaign reports to CVT_FUZZ_REPORT)."""
import collections
import hashlib
import os

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st


def fuzz_settings(default_examples):
    """Hypothesis settings of a fuzz module: CVT_FUZZ_EXAMPLES examples (else the default, a
    count that keeps the module short), the same cases on every run, no example database."""
    examples = int(os.environ.get('CVT_FUZZ_EXAMPLES', str(default_examples)))
    return settings(max_examples=examples, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])

# values a hostile or careless user types: edges of every range, beyond the float range,
# denormals, non-numbers, and plain numbers across 600 decades
EXTREMES = ['0', '-0', '1e-320', '5e-324', '-1e-300', '1e300', '1e308', '-1e308', '1e309', '.inf',
            '-.inf', '.nan', 'nan', '1' + '0' * 400, '-' + '9' * 400, 'true', '[1, 2]', '{a: 1}',
            '0x10', '1_000', '"1"', '', 'abc', '1e', '--1']


def number_texts():
    return st.one_of(
        st.sampled_from(EXTREMES),
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.floats(-330, 308).map(lambda e: f"{10.0 ** e if e < 308 else 1e308:.6g}"),
        st.integers(-10 ** 30, 10 ** 30).map(str))


def leaf(sensible, hostile=0.15):
    """A YAML leaf as text: ``sensible`` (a strategy of texts), else (with about the chance
    ``hostile``) anything."""
    anything = st.one_of(number_texts(), st.sampled_from(['null', '[]', '{}', 'conveyor',
                                                          '"0.05"', '[0.1, 0.2]']))
    return sometimes(hostile, anything, sensible)


def sometimes(chance, rare, usual):
    """``rare`` with about the chance ``chance``, else ``usual``."""
    # (hypothesis leans to the ends of a range and to its first element: 'rare' is neither)
    n = max(3, round(1.0 / chance))
    return st.sampled_from(range(n)).flatmap(lambda i: rare if i == 1 else usual)


def flow(items):
    """A YAML flow map from (key, text) pairs."""
    return '{' + ', '.join(f"{k}: {v}" for k, v in items) + '}'


def mutate(draw, data):
    """``data`` after 1–8 bit flips, deletions and insertions."""
    content = bytearray(data)
    edits = draw(st.lists(st.tuples(st.integers(0, max(len(content) - 1, 0)),
                                    st.sampled_from(['flip', 'delete', 'insert'])),
                          min_size=1, max_size=8))
    for position, kind in edits:
        position = min(position, len(content) - 1)
        if position < 0:
            break
        if kind == 'flip':
            content[position] ^= 1 << draw(st.integers(0, 7))
        elif kind == 'delete':
            del content[position]
        else:
            content[position:position] = draw(st.binary(min_size=1, max_size=4))
    return bytes(content)


def snapshot(folder):
    """Every file under ``folder``: relative path → sha256 of its bytes ('dir' for folders,
    the link text for symbolic links)."""
    found = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            path = os.path.join(root, name)
            rel = os.path.relpath(path, folder)
            if os.path.islink(path):
                found[rel] = 'link:' + os.readlink(path)
            elif os.path.isdir(path):
                found[rel] = 'dir'
            elif os.path.isfile(path):
                with open(path, 'rb') as f:
                    found[rel] = hashlib.sha256(f.read()).hexdigest()
            else:
                found[rel] = 'special'
    return found


def touched(before, after, may_change=()):
    """The files of ``before`` that changed or went, but those in ``may_change``."""
    return sorted(p for p, h in before.items() if after.get(p) != h and p not in may_change)


class Tally(collections.Counter):
    """A surface's case counts; written to CVT_FUZZ_REPORT (a campaign's figures) at the end."""

    def __init__(self, surface):
        super().__init__()
        self.surface = surface

    def outcome(self, outcome):
        self['tried'] += 1
        self['hung' if outcome.hung else f'exit {outcome.code}'] += 1

    def write(self):
        report = os.environ.get('CVT_FUZZ_REPORT')
        if report and self['tried']:
            with open(report, 'a') as f:
                f.write(f"{self.surface}: {dict(sorted(self.items()))}\n")
