"""``cvt_node``: run the device node until SIGINT / SIGTERM."""
import argparse
import faulthandler
import os
import sys

# The loop thread must get the GIL soon after its deadline even while the executor thread is busy
# (a flood of commands): Python's default 5 ms switch interval would be a 5 ms jitter.
GIL_SWITCH_INTERVAL_S = 1e-4
# Fast DDS publishes from the calling thread instead of handing each sample to its writer thread:
# one thread wake-up less per message, which halves a lockstep round trip on a busy machine
# (BENCHMARKS.md, "ROS node"). The user's own setting wins.
PUBLICATION_MODE = ('RMW_FASTRTPS_PUBLICATION_MODE', 'SYNCHRONOUS')
# A shutdown that hangs (a DDS thread, a publisher in use) must not hang ros2 launch or a test:
# this long after the stop began, every thread's stack goes to stderr and the process exits 1.
SHUTDOWN_WATCHDOG_S = 20.0


EPILOG = """\
examples:
  cvt_node                                          # conveyor scene, realtime, 1 kHz
  cvt_node --scene mixer --ros-args -r __ns:=/line1 # another scene, in a namespace
  cvt_node --ros-args --params-file config/scenes/stiff_shaft.yaml -p time_mode:=lockstep
  cvt_node --ros-args -p time_mode:=fast -p publish_rate:=100.0

parameters: `cvt-sim params --node` lists every one (unit, default, range); topics, services,
time modes and diagnostics: docs/node.md; the lockstep protocol: docs/lockstep.md.
"""


def build_parser():
    p = argparse.ArgumentParser(
        prog='cvt_node', description='The pulse CVT as a ROS 2 node (cvt_sim). Parameters come '
        'from\n--ros-args --params-file SCENE.yaml and -p name:=value.', epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--scene', default=None,
                   help='base scene (name such as conveyor, or a path): fills in every parameter '
                        'not set by --params-file / -p. Default: conveyor, or the built-in '
                        'defaults when a --params-file is given (as cvt-sim run reads it)')
    return p


def main(args=None):
    """Run the node until SIGINT / SIGTERM; returns the exit code: 0 when a signal stopped it
    (at any moment, start-up included), 2 for a bad scene or parameter.

    ``args``: the command line without the program name (None: sys.argv[1:]); ROS arguments
    follow ``--ros-args``. Used by the ``cvt_node`` console script and ``cvt-sim node``.
    """
    argv = list(sys.argv[1:] if args is None else args)
    try:
        return _run(argv)
    except KeyboardInterrupt:
        # SIGINT is how a node is stopped (Ctrl-C, ros2 launch's shutdown), also one that is
        # still starting (imports, kernels, discovery): a requested stop, not a failure
        print('cvt_node: stopped during start-up', file=sys.stderr)
        return 0


def _run(argv):
    # imported here, inside main's handling of SIGINT: rclpy and the kernels take a second
    import rclpy
    from rclpy._rclpy_pybind11 import UnknownROSArgsError
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.utilities import remove_ros_args

    from ..parameters import ParameterError
    from ..physics.linkage import GrashofError
    from ..scene import SceneError, params_file_problem
    from .node import DEFAULT_SCENE, CvtSimNode
    from .subscription_wait import RCLError

    try:
        rest = remove_ros_args(['cvt_node'] + argv)[1:]
    except UnknownROSArgsError as exc:   # e.g. `--ros-args --help`: not a ROS argument
        print(f"cvt_node: unknown ROS arguments {exc}; ROS arguments: --ros-args "
              f"[-p NAME:=VALUE] [--params-file FILE] [-r FROM:=TO]; cvt_node --help for the "
              f"rest", file=sys.stderr)
        return 2
    options = build_parser().parse_args(rest)
    if options.scene is not None:
        base = options.scene
    elif '--params-file' in argv:
        base = None
    else:
        base = DEFAULT_SCENE
    faulthandler.enable()   # a crash (in rcl, Fast DDS, a kernel) prints every thread's stack
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    os.environ.setdefault(*PUBLICATION_MODE)
    rclpy.init(args=['cvt_node'] + argv)
    node = executor = None
    try:
        node = CvtSimNode(base_scene=base)
        # a params file whose key misses the node (a namespace, a renamed node) is skipped by
        # ROS without a word: the node would run the defaults, the wrong experiment
        problems = [params_file_problem(path, node.get_fully_qualified_name())
                    for path in _params_files(argv)]
        if any(problems):
            print('\n'.join(f"cvt_node: {p}" for p in problems if p), file=sys.stderr)
            return 2
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        node.start()
        executor.spin()
    except (SceneError, ParameterError, GrashofError) as exc:
        print(f"cvt_node: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass   # a signal at any point after rclpy.init (the node's start included): stop
    except RCLError:
        # a signal's shutdown of the context can land while the executor builds its wait set:
        # rcl refuses the dead context (seen once with SIGTERM on a busy machine)
        if node is None or node.context.ok():
            raise
    finally:
        faulthandler.dump_traceback_later(SHUTDOWN_WATCHDOG_S, exit=True)
        if node is not None:
            node.stop()
            if executor is not None:
                executor.shutdown(timeout_sec=0.5)
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _params_files(argv):
    """The files given with --params-file (ROS arguments)."""
    return [argv[i + 1] for i, arg in enumerate(argv[:-1]) if arg == '--params-file']


if __name__ == '__main__':
    sys.exit(main())
