"""``cvt-sim``, the command line: argument parsing, a library call, an exit code (cli/cvt_sim.py).

``main`` imports the command modules only when called, so that Ctrl-C while the numerical
libraries load is exit code 130, not a traceback.
"""
import sys


def main(argv=None):
    """``cvt-sim ARGS`` (None: sys.argv[1:]); returns the exit code."""
    try:
        from .cvt_sim import main as run
        return run(argv)
    except KeyboardInterrupt:
        print('cvt-sim: interrupted', file=sys.stderr)
        return 130
