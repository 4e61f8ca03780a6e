"""A campaign's output folder: which of its files the sweep may replace.

``OUT`` holds the sweep's own files — ``results.parquet`` (its rows say which campaign they
belong to: table.py), ``campaign.yaml``, ``summary.png``, ``parts/``, ``recordings/`` — and may
hold files of the user's. The sweep replaces ``campaign.yaml`` and ``summary.png`` only when
they are its own output of an earlier run into the same folder: the content hash it wrote is in
``OUT/.cvt_sweep.json`` and still matches (a file the user put there, or edited since, does not).
Anything else is refused before a case runs, unless ``--overwrite`` says to replace it.
Files are written to a temporary name and renamed (whole or absent).
"""
import hashlib
import json
import os
from pathlib import Path

from .table import RESULTS, TableError, campaign_text

MANIFEST = '.cvt_sweep.json'
CAMPAIGN = 'campaign.yaml'
SUMMARY = 'summary.png'
OWN_FILES = (CAMPAIGN, SUMMARY)


def _digest(path):
    h = hashlib.sha256()
    with open(path, 'rb') as f:
        for block in iter(lambda: f.read(1 << 20), b''):
            h.update(block)
    return h.hexdigest()


def _manifest(out):
    """The sweep's record of its files: name → sha256 ({} if none); None if OUT/.cvt_sweep.json
    is there but is not such a record (then it is not the sweep's to replace)."""
    path = Path(out) / MANIFEST
    if not os.path.lexists(path):
        return {}
    try:
        data = json.loads(path.read_text(encoding='utf-8'))
    except (OSError, ValueError):
        return None
    files = data.get('files') if isinstance(data, dict) else None
    if not isinstance(files, dict) or set(data) != {'files'}:
        return None
    return {str(k): str(v) for k, v in files.items()}


def _ours(out, name, manifest, text):
    """True when ``OUT/name`` is absent or the sweep's own earlier output."""
    path = Path(out) / name
    if not os.path.lexists(path):
        return True
    if not path.is_file() or path.is_symlink():
        return False
    try:
        if manifest.get(name) == _digest(path):
            return True
        if name == CAMPAIGN:   # a folder of an earlier version: the campaign its table holds
            written = path.read_text(encoding='utf-8')
            return written == text or written == campaign_text(Path(out) / RESULTS)
    except (OSError, UnicodeDecodeError):
        return False
    return False


def check_folder(out, campaign, overwrite=False):
    """Refuse (TableError) ``out`` if it is not a folder, or holds a campaign.yaml or
    summary.png the sweep did not write there, unless ``overwrite``."""
    out = Path(out)
    try:
        if os.path.lexists(out) and not out.is_dir():
            raise TableError(f"--out {out}: exists and is not a folder")
        if len(out.name.encode()) > 255:
            raise TableError(f"--out {str(out)[:60]}…: a folder name longer than 255 bytes")
    except (OSError, ValueError) as exc:   # (a name the OS refuses)
        raise TableError(f"--out {str(out)[:60]}: cannot be used: {exc}") from None
    if overwrite or not out.is_dir():
        return
    manifest = _manifest(out)
    if manifest is None:
        raise TableError(f"{out / MANIFEST}: exists and is not the sweep's record of its files: "
                         f"use another --out, or --overwrite to replace it")
    for name in OWN_FILES:
        if not _ours(out, name, manifest, campaign.text):
            raise TableError(f"{out / name}: exists and is not this sweep's output (the sweep "
                             f"writes {name} there): use another --out, or --overwrite to "
                             f"replace it")


def write_own(out, name, produce):
    """Write ``OUT/name`` through ``produce(path)`` (a temporary path, renamed onto the target)
    and record its hash as the sweep's own; returns the path (None if ``produce`` wrote
    nothing: a summary with nothing to draw)."""
    out = Path(out)
    target = out / name
    stem, dot, suffix = name.rpartition('.')
    temp = out / f".{stem}.tmp-{os.getpid()}{dot}{suffix}"   # (the suffix: the plot's format)
    try:
        produce(temp)
        if not temp.exists():
            return None
        os.replace(temp, target)
        manifest = _manifest(out) or {}
        manifest[name] = _digest(target)
        record = out / f".{MANIFEST}.tmp-{os.getpid()}"
        record.write_text(json.dumps({'files': manifest}, indent=1, sort_keys=True) + '\n',
                          encoding='utf-8')
        os.replace(record, out / MANIFEST)
    except OSError as exc:
        try:
            temp.unlink()
        except OSError:
            pass
        raise TableError(f"cannot write {target}: {exc.strerror or exc}") from None
    return target


__all__ = ['CAMPAIGN', 'MANIFEST', 'SUMMARY', 'check_folder', 'write_own']
