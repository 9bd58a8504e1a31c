"""Content-addressed results: a key per result from the bytes of its input
files, its options and the code version; objects written atomically.

Layout under ``OUTDIR/.cache``: ``objects/<key[:2]>/<key><suffix>`` (the
result file) and ``<key>.json`` beside it (the job's record: figures,
timings), written after the object, so a record means a complete result.
"""
from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
from pathlib import Path

from .. import __version__
from ..io.atomic import atomic_output

_PACKAGE = Path(__file__).resolve().parents[1]


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """A digest of the package version and every ``.py`` file of the package
    (a code change invalidates every cached result)."""
    h = hashlib.sha256(__version__.encode())
    for f in sorted(_PACKAGE.rglob("*.py")):
        h.update(str(f.relative_to(_PACKAGE)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def file_digest(path) -> str:
    """sha256 of a file's bytes (hex). Raises OSError when it cannot be read."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def result_key(kind: str, digests: list[str], options: dict) -> str:
    """The key of one result: what it is, its inputs' digests (in order), its
    options (JSON-serialisable) and :func:`code_version`."""
    blob = json.dumps({"kind": kind, "inputs": digests, "options": options, "code": code_version()},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()


def atomic_write_bytes(dest, data: bytes) -> Path:
    """Write ``data`` beside ``dest`` and rename it into place
    (:func:`~wearfit_usd.io.atomic.atomic_output`)."""
    with atomic_output(dest) as tmp:
        Path(tmp).write_bytes(data)
    return Path(dest)


class Cache:
    """The result store of one output folder.

    Parameters
    ----------
    root : Path
        ``OUTDIR/.cache``; workers write into it, so on a cluster it must be on
        a file system every worker and the client share.
    """

    def __init__(self, root):
        self.root = Path(root)

    def object_path(self, key: str, suffix: str) -> Path:
        return self.root / "objects" / key[:2] / f"{key}{suffix}"

    def record_path(self, key: str) -> Path:
        return self.root / "objects" / key[:2] / f"{key}.json"

    def lookup(self, key: str) -> dict | None:
        """The stored record of ``key`` if its result is complete, else None."""
        rec = self.record_path(key)
        try:
            record = json.loads(rec.read_text())
        except (OSError, ValueError):
            return None
        obj = record.get("object")
        if obj is None or not Path(obj).exists():
            return None
        return record

    def store_record(self, key: str, record: dict) -> None:
        atomic_write_bytes(self.record_path(key), json.dumps(record, indent=1, default=float).encode())


def publish(src, dest) -> Path:
    """Place a cached object at its output path (a hard link when possible,
    else a copy), atomically replacing what was there."""
    with atomic_output(dest) as tmp:
        try:
            os.link(src, tmp)
        except OSError:
            shutil.copyfile(src, tmp)
    return Path(dest)
