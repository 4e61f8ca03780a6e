"""The design tools' output files: checked before any work (a bad path costs nothing), written
whole (a temporary name, then renamed), never replacing a user's file without ``overwrite``."""
import json
import math
import os

from .errors import DesignError


def check_output(path, setting, overwrite=False, folder=False):
    """Raise DesignError naming ``setting`` (e.g. '--json') if ``path`` cannot be written:
    no such directory, not writable, a directory (a file: for a folder output), or a file
    that exists without ``overwrite``."""
    path = os.fspath(path)
    where = os.path.dirname(os.path.abspath(path))
    if folder:
        if os.path.exists(path) and not os.path.isdir(path):
            raise DesignError(f"{setting} {path}: exists and is not a folder")
        target = path if os.path.isdir(path) else where
        if not os.path.isdir(target):
            raise DesignError(f"{setting} {path}: no such directory {where}")
        if not os.access(target, os.W_OK):
            raise DesignError(f"{setting} {path}: permission denied")
        return
    if os.path.isdir(path):
        raise DesignError(f"{setting} {path}: is a directory")
    if os.path.exists(path) and not overwrite:
        raise DesignError(f"{setting} {path}: file exists (use --overwrite to replace it)")
    if not os.path.isdir(where):
        raise DesignError(f"{setting} {path}: no such directory {where}")
    if not os.access(where if not os.path.exists(path) else path, os.W_OK):
        raise DesignError(f"{setting} {path}: permission denied")


def _finite(value):
    """JSON has no NaN or infinity: they are written as null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def write_json(path, document):
    """``document`` as JSON (non-finite numbers as null), written whole."""
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, 'w', encoding='utf-8') as f:
        json.dump(_finite(document), f, indent=1)
        f.write('\n')
    os.replace(tmp, path)
    return path


__all__ = ['check_output', 'write_json']
