"""Run ``cvt-sim`` commands for the fuzz tests in a separate process, one case at a time, each under
a wall-clock budget: a hang is a failed case (the worker is killed and replaced), not a stuck
test run. The worker imports the package once, so a case costs its own run time only.

``Worker.run(argv)`` → ``Outcome(code, stdout, stderr, traceback, hung)``: ``traceback`` holds the
text of any exception that escaped ``cvt_ros.cli.main()`` (a bug: the CLI turns every error into
one line and an exit code).
"""
import contextlib
import io
import multiprocessing
import os
import re
import traceback
from dataclasses import dataclass

# a number printed as not finite: nan, inf, -inf as words (not inside other words, not '.inf')
NON_FINITE = re.compile(r'(?<![\w.])(nan|-?inf)(?![\w])', re.IGNORECASE)


@dataclass
class Outcome:
    code: int | None
    stdout: str = ''
    stderr: str = ''
    traceback: str = ''
    hung: bool = False

    def problems(self):
        """What breaks the CLI's contract (an empty list: the case was handled)."""
        found = []
        if self.hung:
            found.append('hung (no answer within the time budget)')
        if self.traceback:
            found.append(f'traceback:\n{self.traceback}')
        if 'Traceback (most recent call last)' in self.stderr:
            found.append(f'traceback on stderr:\n{self.stderr[-2000:]}')
        if self.code not in (0, 1, 2, None) and not self.hung:
            found.append(f'exit code {self.code}')
        if self.code == 0 and NON_FINITE.search(self.stdout):
            found.append(f'non-finite number printed with exit 0:\n{self.stdout}')
        if self.code in (1, 2) and not self.stderr.strip() and not re.search(
                r'warning|STOPPED|error', self.stdout):   # (cvt-sim run's warnings: stdout)
            found.append(f'exit code {self.code} without a word on stderr (stdout: '
                         f'{self.stdout[-500:]!r})')
        if self.code == 2 and len(self.stderr.strip().splitlines()) > 3:
            found.append(f'more than one error line:\n{self.stderr}')
        return found


def _serve(connection):
    from cvt_ros.cli import main
    while True:
        argv = connection.recv()
        if argv is None:
            return
        out, err = io.StringIO(), io.StringIO()
        text, code = '', None
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(list(argv))
            except SystemExit as exc:   # argparse: exit 2 with its usage line
                code = exc.code if isinstance(exc.code, int) else 1
            except BaseException:   # noqa: BLE001 — exactly what the fuzz test looks for
                text = traceback.format_exc()
        connection.send((code, out.getvalue(), err.getvalue(), text))


class Worker:
    """One worker process; replaced after a hang."""

    def __init__(self):
        self._context = multiprocessing.get_context('spawn')
        self._start()

    def _start(self):
        self._parent, child = self._context.Pipe()
        self._process = self._context.Process(target=_serve, args=(child,), daemon=True)
        self._process.start()
        # load (or, after a source change, compile) the numba kernels outside any case's budget
        self._parent.send(['warmup'])
        self._parent.recv()

    def run(self, argv, budget):
        """Run ``cvt-sim ARGV``; waits at most ``budget`` seconds for the answer."""
        self._parent.send(list(argv))
        if not self._parent.poll(budget):
            self._process.kill()
            self._process.join()
            self._start()
            return Outcome(None, hung=True)
        try:
            code, out, err, text = self._parent.recv()
        except EOFError:   # the process died (a crash of the interpreter itself)
            self._process.join()
            code = self._process.exitcode
            self._start()
            return Outcome(code, traceback=f'worker died with exit code {code}')
        return Outcome(code, out, err, text)

    def close(self):
        with contextlib.suppress(OSError, BrokenPipeError):
            self._parent.send(None)
        self._process.join(5)
        if self._process.is_alive():
            self._process.kill()


def scaled_budget(seconds):
    """A time budget that stretches on a machine the test is told is slow (CVT_TEST_SLOWDOWN)."""
    return seconds * float(os.environ.get('CVT_TEST_SLOWDOWN', '1'))
