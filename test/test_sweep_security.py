"""A sweep cluster only its owner can use (issue 34): ``cvt-sim sweep --scheduler tls://…`` with
Dask's own TLS security against a real TLS cluster — a ``dask scheduler`` and a ``dask worker``
process, certificates made here with openssl — and plain TCP to another machine refused before
any connection. Dask workers run whatever task they are sent: a scheduler reachable without a
certificate is a door into every worker machine."""
import json
import os
import shutil
import subprocess
import sys
import textwrap
import time

import pytest

from cvt_ros.cli import main as cvt_sim
from cvt_ros.sweep.cluster import SweepError, check_scheduler, open_cluster, tls_security

pytest.importorskip('distributed')
OPENSSL = shutil.which('openssl')
DASK = [sys.executable, '-m', 'distributed.cli.dask_scheduler']
CAMPAIGN = """\
    scene: conveyor
    duration: 0.2
    vary: {load.torque: [4.0, 8.0]}
    """


def _openssl(*args, cwd):
    subprocess.run([OPENSSL, *args], cwd=cwd, check=True, capture_output=True, timeout=120)


def _authority(folder, name):
    _openssl('req', '-x509', '-newkey', 'rsa:2048', '-nodes', '-keyout', f'{name}-key.pem',
             '-out', f'{name}.pem', '-days', '2', '-subj', f'/CN=cvt-test-{name}', cwd=folder)


def _certificate(folder, name, authority):
    _openssl('req', '-newkey', 'rsa:2048', '-nodes', '-keyout', f'{name}-key.pem', '-out',
             f'{name}.csr', '-subj', '/CN=127.0.0.1', cwd=folder)
    _openssl('x509', '-req', '-in', f'{name}.csr', '-CA', f'{authority}.pem', '-CAkey',
             f'{authority}-key.pem', '-CAcreateserial', '-out', f'{name}.pem', '-days', '2',
             cwd=folder)


def _stop(process):
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@pytest.fixture(scope='module')
def tls_cluster(tmp_path_factory):
    """A scheduler and a worker as processes, speaking TLS only, with certificates of a CA made
    here; another CA's certificate for a stranger."""
    if OPENSSL is None:
        pytest.skip('openssl is not installed')
    folder = tmp_path_factory.mktemp('tls')
    _authority(folder, 'ca')
    _certificate(folder, 'node', 'ca')
    _authority(folder, 'other')
    _certificate(folder, 'stranger', 'other')
    tls = ['--tls-ca-file', str(folder / 'ca.pem'), '--tls-cert', str(folder / 'node.pem'),
           '--tls-key', str(folder / 'node-key.pem')]
    scheduler_file = folder / 'scheduler.json'
    log = open(folder / 'cluster.log', 'w')   # noqa: SIM115 — closed below
    scheduler = subprocess.Popen(
        [*DASK, '--protocol', 'tls', '--host', '127.0.0.1', '--port', '0', '--no-dashboard',
         '--scheduler-file', str(scheduler_file), *tls], stdout=log, stderr=subprocess.STDOUT)
    worker = None
    try:
        deadline = time.monotonic() + 120
        while not scheduler_file.exists() or not scheduler_file.stat().st_size:
            assert scheduler.poll() is None, (folder / 'cluster.log').read_text()
            assert time.monotonic() < deadline, 'the scheduler wrote no scheduler file'
            time.sleep(0.1)   # (polling a handshake file the scheduler writes once it listens)
        address = json.loads(scheduler_file.read_text())['address']
        assert address.startswith('tls://127.0.0.1:')
        worker = subprocess.Popen(
            [sys.executable, '-m', 'distributed.cli.dask_worker', address, '--nthreads', '1',
             '--no-nanny', '--no-dashboard', *tls], stdout=log, stderr=subprocess.STDOUT,
            env=dict(os.environ))   # (PYTHONPATH: this checkout's cvt_ros on the worker)
        yield address, folder
    finally:
        if worker is not None:
            _stop(worker)
        _stop(scheduler)
        log.close()


def _campaign(tmp_path):
    path = tmp_path / 'tiny.yaml'
    path.write_text(textwrap.dedent(CAMPAIGN))
    return str(path)


def test_a_sweep_runs_on_a_tls_cluster_with_its_certificates(tls_cluster, tmp_path, capsys):
    address, certs = tls_cluster
    out = tmp_path / 'out'
    code = cvt_sim(['sweep', _campaign(tmp_path), '--out', str(out), '--scheduler', address,
                    '--workers', '1', '--quiet', '--tls-ca', str(certs / 'ca.pem'),
                    '--tls-cert', str(certs / 'node.pem'), '--tls-key',
                    str(certs / 'node-key.pem')])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert '2 cases: 2 ok, 0 failed' in captured.out
    assert (out / 'results.parquet').is_file()


def test_a_tls_scheduler_refuses_a_certificate_of_another_authority(tls_cluster):
    address, certs = tls_cluster
    stranger = tls_security(str(certs / 'ca.pem'), str(certs / 'stranger.pem'),
                            str(certs / 'stranger-key.pem'))
    with pytest.raises(SweepError, match='cannot connect to the scheduler'):
        open_cluster(address, 1, timeout=5.0, security=stranger)


def test_tls_without_certificates_is_refused_before_connecting(tls_cluster, tmp_path, capsys):
    address, _ = tls_cluster
    code = cvt_sim(['sweep', _campaign(tmp_path), '--out', str(tmp_path / 'out'),
                    '--scheduler', address, '--quiet'])
    assert code == 2
    assert 'TLS needs a CA (--tls-ca) and a certificate (--tls-cert)' in capsys.readouterr().err
    assert not (tmp_path / 'out').exists()


@pytest.mark.parametrize('address, allowed', [
    ('tcp://127.0.0.1:8786', True), ('tcp://localhost:8786', True), ('tcp://[::1]:8786', True),
    ('tcp://10.1.2.3:8786', False), ('tcp://192.0.2.7:8786', False),
])
def test_plain_tcp_only_on_this_machine_unless_insecure(address, allowed):
    if allowed:
        assert check_scheduler(address) == (address, None)
        return
    with pytest.raises(SweepError, match='plain TCP to another machine'):
        check_scheduler(address)
    with pytest.warns(UserWarning, match='--insecure'):
        assert check_scheduler(address, insecure=True) == (address, None)


@pytest.mark.parametrize('address', ['foo bar', 'tcp://::::', 'tcp://head', 'ucx://a:1',
                                     'tcp://:8786', 'tcp://h:99999', 'x' * 5000])
def test_a_malformed_scheduler_address_is_one_line(address, tmp_path, capsys):
    code = cvt_sim(['sweep', _campaign(tmp_path), '--out', str(tmp_path / 'out'),
                    '--scheduler', address, '--quiet'])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and 'Traceback' not in err
    assert not (tmp_path / 'out').exists()
