"""Running a campaign on Dask (dask.distributed): a LocalCluster by default, any cluster by
address, the same code path for both.

* :func:`open_cluster` — a LocalCluster with one single-threaded worker *process* per core (the
  kernels are compiled numba code holding the GIL: threads would not run cases in parallel), or
  a Client of an existing scheduler (``tls://HOST:8786`` with Dask's TLS security; plain
  ``tcp://`` only on this machine, or with ``insecure``: :func:`check_scheduler`). Every
  worker, also one that joins or is restarted later, loads the compiled kernels once
  (:class:`WarmKernels`; numba's on-disk cache makes that ~1 s), so no case's wall time
  includes compilation. Workers must run the same cvt_ros version as the client (checked).
* :func:`run_campaign` — submits the cases that are not yet in the table, a bounded window of
  tasks at a time (memory stays flat on both sides however many cases there are), collects rows
  as they finish (any order), writes them in parts and merges the table at the end, or on
  Ctrl-C. Short cases go in batches of ~TASK_SECONDS per task (:class:`_Batches`), so the
  scheduler's round trip (~ms) is paid per batch, not per case.

Faults: a case's own failure is its row (runner.py). A worker that dies mid-task (killed,
segfault, out of memory) loses nothing: the scheduler reruns its task elsewhere; a task that
kills its worker ``distributed.scheduler.allowed-failures`` + 1 times (default 4) is split into
single cases, and a single case that does so twice over is recorded as failed ``killed``. Each
task's rows are collected exactly once (one future per task, released when read) and the table
holds one row per case id.
"""
import contextlib
import itertools
import os
import signal
import threading
import time
import uuid
from dataclasses import dataclass

from .. import __version__
from .cases import build_tasks
from .folder import CAMPAIGN, check_folder, write_own
from .runner import killed_row, run_cases
from .table import ResultStore, TableError, schema, variable_types

WINDOW_PER_THREAD = 4        # tasks in flight per worker thread (keeps every worker busy)
TASK_SECONDS = 0.25          # target wall time of one task (a batch of short cases)
MAX_BATCH = 64               # cases in one task at most
MEASURED = 4                 # cases timed before batches grow
FLUSH_ROWS = 64              # rows per Parquet part
FLUSH_SECONDS = 10.0         # a part at least this often while cases finish (crash: ≤ 10 s lost)


class SweepError(RuntimeError):
    """The campaign cannot run on this cluster (no scheduler at the address, workers without
    cvt_ros, a lost scheduler); the message says what to do."""


def code_fingerprint():
    """A hash of the cvt_ros sources this process runs (every .py file of the package): two
    processes with the same fingerprint compute the same case bit for bit."""
    import hashlib
    from pathlib import Path
    package = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for path in sorted(package.rglob('*.py')):
        digest.update(str(path.relative_to(package)).encode() + b'\0' + path.read_bytes())
    return digest.hexdigest()[:16]


def _identity():
    """What a worker runs (checked against the client)."""
    import platform
    from pathlib import Path
    return {'cvt_ros': __version__, 'code': code_fingerprint(), 'host': platform.node(),
            'path': str(Path(__file__).resolve().parent.parent), 'pid': os.getpid()}


def _warm():
    """Load (or compile, once) the core's kernels by building a simulator of the default scene."""
    from ..parameters import validate
    from ..solver.simulator import Simulator
    Simulator(validate({}))


try:
    from distributed.diagnostics.plugin import WorkerPlugin
except ImportError:        # dask is optional for everything but running a campaign
    WorkerPlugin = object


class WarmKernels(WorkerPlugin):
    """Worker plugin: the kernels are loaded when a worker starts, before it takes a case."""
    name = 'cvt_ros-warm-kernels'

    def setup(self, worker):
        _warm()


class QuietInterrupt(WorkerPlugin):
    """Worker plugin of our own local cluster: its workers ignore SIGINT. Ctrl-C in a terminal
    reaches the whole process group; the client stops the campaign and closes the cluster, and
    each worker would otherwise print a KeyboardInterrupt traceback first. (Not for workers
    the user started: their Ctrl-C is theirs.)"""
    name = 'cvt_ros-quiet-interrupt'

    def setup(self, worker):
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored while worker processes are spawned (they inherit it, and Python keeps an
    inherited SIG_IGN): a Ctrl-C before QuietInterrupt's setup finds them quiet too."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@dataclass
class ClusterHandle:
    client: object
    cluster: object = None        # the LocalCluster we started (None: an existing one)
    dashboard: str = ''
    address: str = ''

    def workers(self):
        """Worker address → number of threads."""
        return dict(self.client.nthreads())

    def close(self):
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _loopback(host):
    """True when every address ``host`` names is on this machine (127.0.0.0/8, ::1)."""
    import ipaddress
    import socket
    if host in ('localhost', 'localhost.localdomain', 'ip6-localhost'):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        found = {info[4][0] for info in socket.getaddrinfo(host, None)}
    except (OSError, UnicodeError):
        return False
    return bool(found) and all(ipaddress.ip_address(a.split('%')[0]).is_loopback
                               for a in found)


def check_scheduler(address, security=None, insecure=False):
    """The scheduler ``address`` as Dask takes it, checked before any connection: a
    ``tcp://`` or ``tls://`` URL with a host and a port; ``tls://`` with a
    :class:`distributed.security.Security` (``security``, or one from the Dask config that
    holds a CA, a certificate and a key). Plain ``tcp://`` to a host other than this machine is
    refused unless ``insecure``: whoever can reach that scheduler runs code on every worker.
    Raises SweepError; returns (address, security or None)."""
    from distributed.comm.addressing import parse_address, parse_host_port
    text = str(address)
    shown = text if len(text) <= 80 else f"{text[:80]}…"
    try:
        scheme, location = parse_address(text, strict=False)
        host, port = parse_host_port(location)
    except (ValueError, TypeError) as exc:
        raise SweepError(f"--scheduler {shown!r}: not a scheduler address ({exc}); e.g. "
                         f"tls://head-node:8786") from None
    if scheme not in ('tcp', 'tls') or not host or not 0 < int(port) < 65536:
        raise SweepError(f"--scheduler {shown!r}: expected tls://HOST:PORT (or tcp://HOST:PORT "
                         f"on this machine), got protocol {scheme!r}, host {host!r}, port "
                         f"{port!r}")
    address = f"{scheme}://{location}"
    if scheme == 'tls':
        from distributed.security import Security
        security = security if security is not None else Security()   # (the Dask config)
        missing = [what for what, value in (('a CA (--tls-ca)', security.tls_ca_file),
                                            ('a certificate (--tls-cert)',
                                             security.tls_client_cert))
                   if not value]
        if missing:
            raise SweepError(f"--scheduler {shown}: TLS needs {' and '.join(missing)}, or "
                             f"distributed.comm.tls.ca-file / client.cert / client.key in the "
                             f"Dask config (docs/sweeps.md)")
        return address, security
    if security is not None:
        raise SweepError(f"--scheduler {shown}: TLS options given for a tcp:// address; use "
                         f"tls://{location}")
    if not _loopback(host):
        if not insecure:
            raise SweepError(f"--scheduler {shown}: plain TCP to another machine: anyone who "
                             f"can reach that scheduler can run any code on its workers, and "
                             f"the cases travel unencrypted. Use tls:// with --tls-ca, "
                             f"--tls-cert, --tls-key (docs/sweeps.md), or --insecure on a "
                             f"network only you use")
        import warnings
        warnings.warn(f"{shown}: plain TCP to another machine (--insecure): whoever can reach "
                      f"the scheduler can run code on its workers", stacklevel=2)
    return address, None


def tls_security(ca=None, cert=None, key=None):
    """A :class:`distributed.security.Security` from the three files (None if none is given;
    the Dask config then decides). Raises SweepError for a missing or unreadable file."""
    if not (ca or cert or key):
        return None
    from distributed.security import Security
    for option, path in (('--tls-ca', ca), ('--tls-cert', cert), ('--tls-key', key)):
        if option != '--tls-key' and not path:
            raise SweepError(f"{option}: missing (TLS needs the CA, the certificate and its "
                             f"key)")
        if path and not os.path.isfile(path):
            raise SweepError(f"{option} {path}: no such file")
    try:
        return Security(tls_ca_file=ca, tls_client_cert=cert, tls_client_key=key,
                        require_encryption=True)
    except (OSError, ValueError) as exc:
        raise SweepError(f"--tls-ca/--tls-cert/--tls-key: cannot be used: {exc}") from None


def open_cluster(scheduler=None, workers=None, dashboard='127.0.0.1:8787', timeout=60.0,
                 security=None, insecure=False):
    """A LocalCluster of ``workers`` single-threaded processes (default: one per core; its
    scheduler listens on this machine only), or a client of the scheduler at ``scheduler``
    (:func:`check_scheduler`: ``security`` for tls://; waiting up to ``timeout`` s for
    ``workers`` workers, default 1). Raises SweepError."""
    import logging
    import ssl

    import dask
    from distributed import Client, LocalCluster

    cluster = None
    if scheduler:
        scheduler, security = check_scheduler(scheduler, security, insecure)
    try:
        if scheduler:
            client = Client(scheduler, timeout=timeout, security=security)
        else:
            # the statistical profiler samples every worker thread 100 times a second: a few
            # per cent of a core, and nothing to see inside compiled kernels. A saturation of 1
            # sends a worker one task per thread, no more: when a worker dies, only the task it
            # was running counts against the case (queued ones are not blamed), and a batch of
            # ~0.25 s pays one round trip (~1 ms) of idle time
            with dask.config.set({'distributed.worker.profile.enabled': False,
                                  'distributed.scheduler.worker-saturation': 1.0}):
                with _sigint_ignored():
                    cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1,
                                           threads_per_worker=1, processes=True,
                                           dashboard_address=dashboard,
                                           silence_logs=logging.ERROR)
            client = Client(cluster)
    except (OSError, TimeoutError, RuntimeError, ValueError, ssl.SSLError) as exc:
        # (LocalCluster raises RuntimeError when it cannot start: e.g. a dashboard host that
        # does not resolve)
        if cluster is not None:
            cluster.close()
        if scheduler:
            raise SweepError(f"cannot connect to the scheduler at {scheduler}: {exc}") from None
        raise SweepError(f"cannot start a local cluster (dashboard at {dashboard}): "
                         f"{exc}") from None
    handle = ClusterHandle(client, cluster, client.dashboard_link or '',
                           client.scheduler.address)
    try:
        if scheduler:
            client.wait_for_workers(workers or 1, timeout=timeout)
        _check_workers(client)
        client.register_plugin(WarmKernels(), name=WarmKernels.name)
        if cluster is not None:
            client.register_plugin(QuietInterrupt(), name=QuietInterrupt.name)
    except BaseException as exc:
        handle.close()
        if isinstance(exc, (SweepError, KeyboardInterrupt)):
            raise
        raise SweepError(f"the workers of {handle.address} cannot run cases: {exc!r} (is the "
                         f"same cvt_ros installed on every worker machine? docs/sweeps.md)"
                         ) from None
    return handle


def _check_workers(client):
    """Every worker runs the same cvt_ros code as this client (else the table would depend on
    which worker ran a case)."""
    found = client.run(_identity)
    mine = _identity()
    wrong = {addr: info for addr, info in found.items()
             if (info['cvt_ros'], info['code']) != (mine['cvt_ros'], mine['code'])}
    if wrong:
        addr, info = next(iter(wrong.items()))
        raise SweepError(f"worker {addr} on {info['host']} runs cvt_ros {info['cvt_ros']} from "
                         f"{info['path']} (code {info['code']}), this client {mine['cvt_ros']} "
                         f"from {mine['path']} (code {mine['code']}); {len(wrong)} of "
                         f"{len(found)} workers differ: install the same revision everywhere "
                         f"(the cases' numbers depend on it)")


@dataclass
class CampaignRun:
    """What :func:`run_campaign` did: the table's rows (case order) and the counts."""
    rows: list
    path: object
    total: int
    skipped: int
    ran: int
    failed: int
    wall_time: float
    problems: list


@dataclass
class Plan:
    """A campaign against its output folder: every task, the table, what is left to run."""
    campaign: object
    tasks: list
    store: ResultStore
    order: dict                   # case_id → case index
    todo: list

    @property
    def skipped(self):
        return len(self.tasks) - len(self.todo)


def plan_campaign(campaign, out_dir, *, tasks=None, retry_failed=False, overwrite=False):
    """Check ``out_dir``'s table against the campaign and list the cases to run (no cluster
    needed). Raises CampaignError (a case that cannot run), TableError (the folder holds
    another campaign's rows, files of the user's where the sweep writes its own — unless
    ``overwrite`` — or cannot be written)."""
    check_folder(out_dir, campaign, overwrite)
    tasks = build_tasks(campaign, out_dir) if tasks is None else tasks
    order = {t.case_id: t.index for t in tasks}
    store = ResultStore(out_dir, schema(campaign, variable_types(tasks,
                                                                 campaign.variable_names)))
    store.prepare()
    done = store.done()
    foreign = [cid for cid in done if cid not in order]
    if foreign:
        raise TableError(f"{store.path}: {len(foreign)} of its {len(done)} cases are not cases "
                         f"of {campaign.path} (another campaign, or this one with other "
                         f"settings or metrics): use another --out, or move the table away")
    # a case done before without the recording this campaign asks for runs again to make it
    # (record: added to a campaign whose table holds its cases)
    todo = [t for t in tasks if t.case_id not in done
            or (retry_failed and done[t.case_id]['status'] != 'ok')
            or (t.record and done[t.case_id]['status'] == 'ok' and not os.path.exists(t.record))]
    return Plan(campaign, tasks, store, order, todo)


def run_campaign(campaign, out_dir, handle=None, *, plan=None, retry_failed=False,
                 on_event=None):
    """Run the campaign's cases that ``out_dir``'s table does not hold yet on the cluster of
    ``handle`` (needed only if there are any); returns a :class:`CampaignRun`.
    ``on_event(kind, info)`` hears 'start' (total, skipped, todo) and 'case' (the row) events.
    Raises CampaignError, TableError, SweepError; on KeyboardInterrupt the finished rows are
    merged into the table before it propagates."""
    plan = plan or plan_campaign(campaign, out_dir, retry_failed=retry_failed)
    store, todo = plan.store, plan.todo
    write_own(store.dir, CAMPAIGN, lambda path: path.write_text(campaign.text,
                                                                 encoding='utf-8'))
    event = on_event or (lambda kind, info: None)
    event('start', {'total': len(plan.tasks), 'skipped': plan.skipped, 'todo': len(todo)})
    start = time.perf_counter()
    failed = 0
    try:
        if todo:
            failed = _run(handle, todo, store, event)
    finally:
        rows = store.merge(plan.order)
    return CampaignRun(rows, store.path, len(plan.tasks), plan.skipped, len(todo), failed,
                       time.perf_counter() - start, store.problems)


class _Batches:
    """Cases handed out in batches (one Dask task each) sized so a task takes ~TASK_SECONDS:
    short cases then cost one scheduler round trip per batch, not per case. Sizes follow the
    mean case time measured so far (1 until MEASURED cases are in), and stay small enough near
    the end that every worker keeps busy. A batch whose worker died is split into single cases
    (so only the case that kills workers ends ``killed``)."""

    def __init__(self, todo, threads):
        self.pending = list(reversed(todo))    # pop() from the end: case order
        self.threads = threads
        self.done = 0
        self.busy = 0.0
        self.second_chance = set()      # cases that died alone once already

    def record(self, rows):
        times = [r['wall_time'] for r in rows if r['wall_time'] == r['wall_time']]
        self.done += len(times)
        self.busy += sum(times)

    def size(self):
        if self.done < MEASURED or self.busy <= 0:
            return 1
        size = round(TASK_SECONDS / (self.busy / self.done))
        spread = len(self.pending) // (2 * max(self.threads, 1))   # ≥ 2 batches per thread left
        return max(1, min(MAX_BATCH, size, spread))

    def take(self):
        return [self.pending.pop() for _ in range(min(self.size(), len(self.pending)))]

    def split(self, batch):
        self.pending.extend(reversed(batch))


def _run(handle, todo, store, event):
    """Submit ``todo`` in batches, a window at a time; collect rows as they finish; the number
    of failed cases."""
    from distributed import KilledWorker, as_completed

    if handle is None:
        raise SweepError(f"{len(todo)} cases to run and no cluster given")
    client = handle.client
    nonce = uuid.uuid4().hex[:8]
    serial = itertools.count()
    batches = _Batches(todo, sum(handle.workers().values()))
    in_flight = {}
    finished = as_completed()
    failed = 0
    last_flush = time.perf_counter()

    def submit(count):
        for _ in range(count):
            batch = batches.take()
            if not batch:
                return
            # a key per submission: a batch split or retried after its worker died must not
            # find the dead task's key still on the scheduler
            key = f"cvt-cases-{batch[0].index}-{len(batch)}-{nonce}-{next(serial)}"
            future = client.submit(run_cases, batch, key=key, pure=False)
            in_flight[future.key] = batch
            finished.add(future)

    def window():
        batches.threads = sum(handle.workers().values())
        return max(8, WINDOW_PER_THREAD * batches.threads)

    try:
        submit(window())
        for future in finished:
            batch = in_flight.pop(future.key)
            # a batch whose workers died: its cases one by one; a single case once more (a task
            # queued or just sent to a dying worker is blamed with the one that killed it)
            retry = len(batch) > 1 or batch[0].index not in batches.second_chance
            rows = _collect(future, batch, KilledWorker, retry)
            future.release()
            if rows is None:
                batches.second_chance.update(t.index for t in batch if len(batch) == 1)
                batches.split(batch)
                submit(len(batch))
                continue
            batches.record(rows)
            for row in rows:
                store.add(row)
                failed += row['status'] != 'ok'
                event('case', row)
            now = time.perf_counter()
            if len(store.pending) >= FLUSH_ROWS or now - last_flush >= FLUSH_SECONDS:
                store.flush()
                last_flush = now
                submit(window() - len(in_flight))
            else:
                submit(1)
    except BaseException:
        try:
            client.cancel(list(finished.futures))
        except Exception:   # noqa: BLE001, S110 — a lost scheduler has nothing to cancel
            pass
        raise
    return failed


def _collect(future, batch, killed, retry):
    """The rows of a finished batch: its result; None when its worker died and ``retry`` says
    to run it again; else failed rows that say what happened."""
    from distributed.client import FutureCancelledError
    try:
        return future.result()
    except killed as exc:
        if retry:
            return None
        return [killed_row(batch[0], f"its worker process died every time it ran this case "
                                     f"(a crash, or out of memory?): {exc}")]
    except FutureCancelledError:
        raise SweepError(f"case {batch[0].index} was cancelled: the scheduler is gone; the cases "
                         f"done are in the table, run again to resume") from None
    except Exception as exc:   # noqa: BLE001 — the task could not even start on its worker
        rows = [killed_row(task, f"the case could not run on its worker: {exc!r}")
                for task in batch]
        for row in rows:
            row['failure'] = 'error'
        return rows


__all__ = ['CampaignRun', 'ClusterHandle', 'Plan', 'SweepError', 'WarmKernels', 'check_scheduler',
           'open_cluster', 'plan_campaign', 'run_campaign', 'tls_security']
