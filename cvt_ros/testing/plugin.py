"""pytest plugin: the ``cvt_device`` fixture, the ``--cvt-backend`` option and the
``cvt_backend`` marker (see ``cvt_ros.testing``). Imports nothing of ROS until a test asks for
the dds back end."""
import pytest

# (cvt_ros.scenario.BACKENDS; spelled out so that loading the plugin into every pytest run of
# the environment imports nothing heavy)
BACKENDS = ('offline', 'lockstep', 'dds')


def pytest_addoption(parser):
    group = parser.getgroup('cvt_ros', 'cvt_ros controller tests')
    group.addoption('--cvt-backend', choices=BACKENDS, default=None,
                    help='back end of the cvt_device fixture for every test (default: the '
                         "test's cvt_backend marker, else lockstep)")


def pytest_configure(config):
    config.addinivalue_line(
        'markers', 'cvt_backend(name): back end of the cvt_device fixture for this test '
                   '(offline, lockstep or dds)')


@pytest.fixture
def cvt_device(request):
    """The device under test (a DeviceUnderTest); released after the test."""
    from .device import DeviceUnderTest
    backend = request.config.getoption('--cvt-backend')
    marker = request.node.get_closest_marker('cvt_backend')
    if backend is None:
        backend = marker.args[0] if marker is not None and marker.args else 'lockstep'
    with DeviceUnderTest(backend) as device:
        yield device
