"""rosbag2-compatible (ROS 2 Jazzy) MCAP recording: write, read tolerantly, recover after crashes.

Importing this package does not import rclpy; rclpy is loaded only when a message object is
serialized or deserialized, or a recording is replayed (:func:`.replay.replay`). The
simulation's recorder (:class:`SimulationRecorder`, :mod:`.recorder`) is loaded on first use (it
imports the interface and the solver's sample layout).

Typical use (in a node)::

    writer = BagWriter('run.mcap')
    writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState', qos=publisher.qos_profile)
    writer.write('/joint_states', msg, node.get_clock().now().nanoseconds)
    writer.finish()
"""

from .definitions import (
    MessageDefinition,
    get_message_definition,
    message_class,
    message_definition_text,
    normalize_type_name,
    type_description_hash,
    type_name_of,
)
from .errors import (
    LogTimeError,
    MessageDefinitionError,
    OutputError,
    RecordingError,
    RecordingReadError,
    RecordingReadWarning,
    ReplayError,
)
from .outputs import OutputFiles
from .qos import DURATION_INFINITE, offered_qos_profiles_yaml, qos_profile_dict
from .reader import BagMessage, BagSummary, TopicSummary, read_messages, summary
from .recover import Recovery, recover, recover_file
from .writer import DEFAULT_CHUNK_SIZE, BagWriter

__all__ = [
    'BagMessage',
    'BagSummary',
    'BagWriter',
    'DEFAULT_CHUNK_SIZE',
    'DURATION_INFINITE',
    'LogTimeError',
    'MessageDefinition',
    'MessageDefinitionError',
    'OutputError',
    'OutputFiles',
    'RecordingError',
    'RecordingReadError',
    'RecordingReadWarning',
    'Recovery',
    'ReplayError',
    'SimulationRecorder',
    'TopicSummary',
    'check_target',
    'get_message_definition',
    'message_class',
    'message_definition_text',
    'normalize_type_name',
    'offered_qos_profiles_yaml',
    'qos_profile_dict',
    'read_messages',
    'record_run',
    'recover',
    'recover_file',
    'summary',
    'type_description_hash',
    'type_name_of',
    'write_run',
]

_RECORDER = frozenset({'SimulationRecorder', 'check_target', 'record_run', 'write_run'})


def __getattr__(name: str):
    if name not in _RECORDER:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    from . import recorder

    return getattr(recorder, name)
