"""Server-side store of result files for download: one folder per result, keyed by a random id, with expiry.

Clients name a result by its id and a file by the name the result itself lists in ``files``; both are looked up
in the store's own table, so nothing a client sends becomes part of a path on disk.
"""

from __future__ import annotations

import logging
import re
import secrets
import shutil
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from footmesh import report

log = logging.getLogger(__name__)

RESULT_ID = re.compile(r"^[A-Za-z0-9_-]{22}$")
"""What ``secrets.token_urlsafe(16)`` gives: 128 random bits."""
SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")
"""A file name a result may list: one plain name, no folders."""


@dataclass(frozen=True)
class StoredResult:
    """One stored result: its id, the result dictionary, its files (name -> path) and when it expires."""

    rid: str
    result: dict[str, Any]
    files: dict[str, Path]
    expires: float


class ResultStore:
    """Result folders under one temporary root; entries expire after ``ttl_s``, at most ``max_entries`` kept.

    Thread-safe: results are added from worker threads and read from the server's event loop.
    """

    def __init__(self, root: Path | None = None, ttl_s: float = 3600.0, max_entries: int = 200) -> None:
        self.root = Path(tempfile.mkdtemp(prefix="footmesh-results-", dir=root))
        self.ttl_s = ttl_s
        self.max_entries = max_entries
        self._entries: dict[str, StoredResult] = {}
        self._lock = threading.Lock()

    def add(self, result: dict[str, Any], out_dir: Path) -> str:
        """Move the files that ``result["files"]`` lists from ``out_dir`` into a new entry; returns its id.

        Names that are not plain file names, or that are missing or not regular files, are left out (logged).
        A ``result.json`` is written from ``result`` when the pipeline did not list one.
        """
        rid = secrets.token_urlsafe(16)
        folder = self.root / rid
        folder.mkdir()
        listed = result.get("files") or {}
        files: dict[str, Path] = {}
        for key, name in listed.items() if isinstance(listed, dict) else ():
            source = out_dir / name if isinstance(name, str) and SAFE_NAME.match(name) else None
            if source is None or source.is_symlink() or not source.is_file():
                log.warning("result file %s=%r is not a plain file in the output folder; not offered", key, name)
                continue
            files[name] = Path(shutil.move(source, folder / name))
        if "result.json" not in files:
            report.write_json(folder / "result.json", result)
            files["result.json"] = folder / "result.json"
        entry = StoredResult(rid, result, files, time.monotonic() + self.ttl_s)
        with self._lock:
            self._entries[rid] = entry
        self.sweep()
        return rid

    def get(self, rid: str) -> StoredResult | None:
        """The entry with this id, or None (unknown, malformed or expired id)."""
        if not isinstance(rid, str) or not RESULT_ID.match(rid):
            return None
        with self._lock:
            entry = self._entries.get(rid)
        if entry is None or entry.expires < time.monotonic():
            self.sweep()
            return None
        return entry

    def file(self, rid: str, name: str) -> Path | None:
        """The path of file ``name`` of result ``rid``, or None; ``name`` is only ever a key of the table."""
        entry = self.get(rid)
        return None if entry is None else entry.files.get(name)

    def sweep(self) -> int:
        """Delete expired entries and the oldest beyond ``max_entries``; returns how many were deleted."""
        now = time.monotonic()
        with self._lock:
            by_age = sorted(self._entries.values(), key=lambda e: e.expires)
            excess = max(0, len(by_age) - self.max_entries)
            doomed = [e.rid for i, e in enumerate(by_age) if i < excess or e.expires < now]
            for rid in doomed:
                del self._entries[rid]
        for rid in doomed:
            shutil.rmtree(self.root / rid, ignore_errors=True)
        return len(doomed)

    def __len__(self) -> int:
        with self._lock:
            return len(self._entries)

    def close(self) -> None:
        """Delete every entry and the root folder."""
        with self._lock:
            self._entries.clear()
        shutil.rmtree(self.root, ignore_errors=True)
