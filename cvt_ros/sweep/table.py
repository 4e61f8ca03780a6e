"""The results table: one Parquet row per case, written so that a crash loses almost nothing
and a rerun skips what is done.

While a campaign runs, finished rows are written in small Parquet *parts*
(``OUT/parts/part-NNNNNN.parquet``, each written to a temporary name and renamed: a part is
whole or absent). At the end — or on Ctrl-C — the parts and the previous table are merged into
``OUT/results.parquet`` (case order, one row per case id, written the same way) and the parts
removed. A rerun reads both back (:meth:`ResultStore.done`), so a campaign killed in any way
resumes where its last part ended.

Columns: ``case`` (index in the campaign), ``case_id``, the varied parameters (named as in the
campaign), the metrics (and ``steady``, ``window_start`` for scene campaigns), ``status``
(ok | failed), ``failure`` (timeout | diverged | controller | error | killed), ``error``,
``warnings``, ``wall_time`` [s]. Units are in each field's metadata (``unit``); the campaign
file's text, the cvt_ros version and the metric definitions are in the file's metadata.
"""
import math
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from .. import __version__, parameters
from .metrics import SCENARIO_METRICS, SCENE_METRICS, WINDOW_COLUMNS

RESULTS = 'results.parquet'
PARTS = 'parts'


class TableError(RuntimeError):
    """The output folder cannot hold this campaign's table (another campaign's rows, a damaged
    or unwritable file); the message says which file and what to do."""


def unit_of(name):
    """The unit of a varied parameter (its spec; controller settings by name)."""
    if name.startswith('controller.'):
        return {'kp': 'm/(rad/s)', 'ki': 'm/rad', 'rate_limit': 'm/s',
                'tracking_time': 's'}.get(name.partition('.')[2], 'm')
    spec = parameters.SPECS.get(name)
    return spec.unit if spec else ''


def schema(campaign, variable_types):
    """The table's schema: ``variable_types`` name → 'number' | 'text' of the varied values."""
    metrics = getattr(campaign, 'metric_table', None) or (
        SCENE_METRICS if campaign.kind == 'scene' else SCENARIO_METRICS)
    fields = [pa.field('case', pa.int64(), metadata={'unit': '-'}),
              pa.field('case_id', pa.string())]
    for name in campaign.variable_names:
        kind = pa.float64() if variable_types[name] == 'number' else pa.string()
        fields.append(pa.field(name, kind, metadata={'unit': unit_of(name), 'role': 'parameter'}))
    for name in campaign.metrics:
        fields.append(pa.field(name, pa.float64(),
                               metadata={'unit': metrics[name][0], 'role': 'metric',
                                         'meaning': metrics[name][1]}))
    if campaign.kind == 'scene':
        fields.append(pa.field('steady', pa.bool_(), metadata={'meaning':
                                                               WINDOW_COLUMNS['steady'][1]}))
        fields.append(pa.field('window_start', pa.float64(), metadata={'unit': 's'}))
    fields += [pa.field('status', pa.string()), pa.field('failure', pa.string()),
               pa.field('error', pa.string()), pa.field('warnings', pa.string()),
               pa.field('wall_time', pa.float64(), metadata={'unit': 's'})]
    meta = {'cvt_ros.campaign': campaign.text, 'cvt_ros.campaign_path': str(campaign.path),
            'cvt_ros.campaign_name': campaign.name, 'cvt_ros.version': __version__,
            'cvt_ros.kind': campaign.kind}
    return pa.schema(fields, metadata=meta)


def _table(rows, schema_):
    columns = {f.name: [row.get(f.name) for row in rows] for f in schema_}
    for f in schema_:
        if pa.types.is_floating(f.type):   # None stays null; NaN stays NaN
            columns[f.name] = [None if v is None else float(v) for v in columns[f.name]]
        elif pa.types.is_string(f.type):
            columns[f.name] = [None if v is None else str(v) for v in columns[f.name]]
    return pa.table(columns, schema=schema_)


def _write(table, path):
    """Write ``table`` to ``path`` whole or not at all (temporary file, fsync, rename)."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        pq.write_table(table, tmp, compression='zstd')
        with open(tmp, 'rb') as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except (OSError, pa.ArrowException) as exc:   # (disk full, quota, I/O error)
        try:
            tmp.unlink()
        except OSError:
            pass
        raise TableError(f"cannot write {path}: {getattr(exc, 'strerror', None) or exc}"
                         ) from None


def read_rows(path):
    """The rows of a results table or part (list of dicts); TableError for a Parquet file that
    is not one (no case_id column: not written by a sweep)."""
    table = pq.read_table(path)
    if 'case_id' not in table.column_names:
        raise TableError(f"{path}: a Parquet file, but not a results table of cvt-sim sweep (no "
                         f"case_id column); move it away or use another --out")
    return table.to_pylist()


def campaign_text(path):
    """The campaign file's text a results table was written for ('' if none can be read)."""
    try:
        meta = pq.read_schema(path).metadata or {}
        return meta.get(b'cvt_ros.campaign', b'').decode('utf-8')
    except (OSError, pa.ArrowException, UnicodeDecodeError):
        return ''


class ResultStore:
    """The table of one campaign in ``out_dir``: what is done, new rows, the merge."""

    def __init__(self, out_dir, schema_):
        self.dir = Path(out_dir)
        self.schema = schema_
        self.pending = []
        self.problems = []          # damaged parts skipped (their cases run again)
        self._next_part = 0
        self._read_parts = []

    @property
    def path(self):
        return self.dir / RESULTS

    def _files(self):
        parts = sorted((self.dir / PARTS).glob('part-*.parquet'))
        return ([self.path] if self.path.exists() else []) + parts

    def done(self):
        """case_id → row of every case already in the table or a part (a later part wins)."""
        rows = {}
        self._read_parts = []
        for f in self._files():
            try:
                found = read_rows(f)
            except (OSError, pa.ArrowException, TableError) as exc:
                if f == self.path:
                    if isinstance(exc, TableError):
                        raise
                    raise TableError(f"{f}: not a readable results table ({exc}); move it away "
                                     f"or use another --out") from None
                self.problems.append(f"{f}: unreadable part skipped and kept ({exc})")
                continue
            if f != self.path:
                self._read_parts.append(f)
            for row in found:
                rows[row['case_id']] = row
        numbers = [int(f.stem.rpartition('-')[2]) for f in self._files()
                   if f.parent.name == PARTS and f.stem.rpartition('-')[2].isdigit()]
        self._next_part = max(numbers, default=-1) + 1
        return rows

    def prepare(self):
        try:
            (self.dir / PARTS).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise TableError(f"{self.dir}: cannot create the output folder: "
                             f"{exc.strerror or exc}") from None

    def add(self, row):
        self.pending.append(row)

    def flush(self):
        """Write the pending rows as one part (nothing if none)."""
        if not self.pending:
            return
        path = self.dir / PARTS / f"part-{self._next_part:06d}.parquet"
        _write(_table(self.pending, self.schema), path)
        self._next_part += 1
        self.pending = []

    def merge(self, order):
        """Write results.parquet from everything done: the cases of ``order`` (case_id → index
        in this campaign) in case order, ``case`` renumbered; then remove the parts. Returns the
        rows written."""
        self.flush()
        rows = [dict(row, case=order[cid]) for cid, row in self.done().items() if cid in order]
        rows.sort(key=lambda r: r['case'])
        _write(_table(rows, self.schema), self.path)
        for f in self._read_parts:   # (merged; a part that could not be read stays)
            f.unlink()
        try:
            (self.dir / PARTS).rmdir()
        except OSError:
            pass
        return rows


def is_number(value):
    return value is None or (isinstance(value, (int, float)) and not isinstance(value, bool)
                             and not (isinstance(value, float) and math.isnan(value)))


def variable_types(tasks, names):
    """'number' for a varied parameter whose every value is a number, else 'text'."""
    return {name: 'number' if all(is_number(t.variables.get(name)) for t in tasks) else 'text'
            for name in names}


__all__ = ['RESULTS', 'ResultStore', 'TableError', 'is_number', 'read_rows', 'schema', 'unit_of',
           'variable_types']
