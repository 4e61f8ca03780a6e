"""The sweep's input error (a class of its own, so every module of the room can raise it)."""
from ..yaml_file import InputFileError


class CampaignError(InputFileError):
    """A campaign that cannot be run; the message names the file, the key, the value and why."""
