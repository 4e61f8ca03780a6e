"""Test your controller against the device in a few lines of pytest.

The plugin (``cvt_ros.testing.plugin``; registered as a pytest11 entry point, so installing
cvt_ros is enough — or add ``pytest_plugins = ['cvt_ros.testing.plugin']`` to your conftest.py)
gives the fixture ``cvt_device``::

    def test_my_controller_rejects_a_load_step(cvt_device):
        run = cvt_device.run('conveyor_load_step', controller=MyController())
        assert run.ok, run.error
        assert run.metrics['max_deviation'] < 1.0           # rad/s
        assert run.metrics['settling_time'] < 2.0           # s

``cvt_device.backend`` is ``lockstep`` (the device core in the test process) unless the test is
marked ``@pytest.mark.cvt_backend('dds')`` (``cvt_node`` in a process of its own, on a ROS
domain held for the test alone) or pytest runs with ``--cvt-backend offline|lockstep|dds``.
"""
from .device import DeviceUnderTest

__all__ = ['DeviceUnderTest']
