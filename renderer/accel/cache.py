"""A disk cache of built trees (and other arrays), keyed by their content.

An entry is one file ``<folder>/<kind>-<key>.bin``: the magic line ``MAGIC``, the SHA-256
of the payload (32 bytes), then the payload, an uncompressed ``.npz`` of named arrays
plus a ``meta`` JSON string that repeats the key. The key (``content_key``) hashes the
input bytes, the producer and its parameters and ``code_version()`` (the source text of the
modules that write the layout), so any change of triangles, builder, parameter or code
misses.

- written atomically (``renderer.outputs.atomic_path``): a reader sees a whole entry or
  none; two processes writing one key both write the same bytes and the last rename wins;
- verified on read: a short, corrupt or foreign entry (bad magic, digest, key or arrays)
  is never trusted: ``get`` warns once (``CacheWarning``), removes it where it can and
  returns None, so the caller rebuilds;
- bounded: after each write the least recently used entries (file mtimes, touched on
  every hit) are removed until the folder holds at most ``max_bytes``;
- optional: a folder that cannot be made or written leaves the cache read-only or off,
  without an error (one warning on the first failed write);
- in the background on request (``background=True``: the command line): ``put`` hands
  the write to a thread and returns, so a cold process renders while its entries are
  written; ``flush`` waits for them (a process that ends first still leaves whole entries
  or none, by the atomic rename).

The folder is ``$WHITTED_CACHE`` when set, else the user cache folder
(``$XDG_CACHE_HOME/whitted``, ``~/.cache/whitted``; ``~/Library/Caches/whitted`` on macOS).
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import sys
import threading
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..cache_key import CODE_MODULES, code_version, content_key
from ..outputs import OutputError, atomic_path

__all__ = ["CODE_MODULES", "MAGIC", "MAX_BYTES", "CacheWarning", "TreeCache", "code_version",
           "content_key", "default_folder"]

MAGIC = b"whitted-cache 1\n"
#: Default bound on the folder's size (bytes).
MAX_BYTES = 2 << 30
class CacheWarning(UserWarning):
    """A cache entry that could not be used or written (the work is redone)."""


def default_folder() -> Path:
    """``$WHITTED_CACHE``, else the user cache folder's ``whitted``."""
    env = os.environ.get("WHITTED_CACHE")
    if env:
        return Path(env).expanduser()
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "whitted"
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "whitted"


@dataclass
class TreeCache:
    """The cache in ``folder`` (None: ``default_folder()``), at most ``max_bytes``.
    ``hits``/``misses``/``rejected`` count ``get`` answers in this process."""

    folder: Path | None = None
    max_bytes: int = MAX_BYTES
    hits: int = 0
    misses: int = 0
    rejected: int = 0
    background: bool = False
    _write_warned: bool = False
    _pending: list = field(default_factory=list, repr=False)

    def __post_init__(self):
        self.folder = default_folder() if self.folder is None else Path(self.folder)

    def path(self, kind: str, key: str) -> Path:
        return self.folder / f"{kind}-{key}.bin"

    def get(self, kind: str, key: str) -> dict | None:
        """The arrays stored under ``key`` (a dict of name -> numpy array, plus ``meta``:
        the stored dict), or None on a miss or an entry that fails verification (then one
        ``CacheWarning``, and the entry is removed where the folder allows)."""
        p = self.path(kind, key)
        try:
            data = p.read_bytes()
        except (FileNotFoundError, NotADirectoryError):
            self.misses += 1
            return None
        except OSError as e:
            self.misses += 1
            warnings.warn(f"{p}: cache entry unreadable ({e.strerror or e}); rebuilding",
                          CacheWarning, stacklevel=2)
            return None
        try:
            out = _decode(data, kind, key)
        except ValueError as e:
            self.rejected += 1
            warnings.warn(f"{p}: cache entry {e}; rebuilding", CacheWarning, stacklevel=2)
            try:
                p.unlink()
            except OSError:
                pass
            return None
        self.hits += 1
        try:
            os.utime(p)                  # most recently used
        except OSError:
            pass
        return out

    def put(self, kind: str, key: str, arrays: dict, meta: dict | None = None) -> bool:
        """Store ``arrays`` (name -> numpy array) and ``meta`` (JSON-able) under ``key``,
        atomically, then trim the folder to ``max_bytes``. Returns False (one
        ``CacheWarning`` per cache) where the folder cannot be written. With
        ``background``, the write runs on a thread (``flush`` waits) and True is returned
        at once (the arrays must not change afterwards)."""
        if self.background:
            th = threading.Thread(target=self._write, args=(kind, key, arrays, meta),
                                  name=f"cache {kind}")
            th.start()
            self._pending.append(th)
            return True
        return self._write(kind, key, arrays, meta)

    def flush(self) -> None:
        """Wait for the writes ``put`` handed to threads (``background``)."""
        while self._pending:
            self._pending.pop().join()

    def _write(self, kind: str, key: str, arrays: dict, meta: dict | None) -> bool:
        payload = _encode(arrays, dict(meta or {}, kind=kind, key=key))
        blob = MAGIC + hashlib.sha256(payload).digest() + payload
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with atomic_path(self.path(kind, key), overwrite=True) as tmp:
                with open(tmp, "wb") as f:
                    f.write(blob)
        except (OutputError, OSError) as e:
            if not self._write_warned:
                self._write_warned = True
                warnings.warn(f"{self.folder}: cache not written ({e}); working without it",
                              CacheWarning, stacklevel=2)
            return False
        self.trim()
        return True

    def trim(self) -> None:
        """Remove the least recently used entries until the folder holds ``max_bytes``."""
        try:
            entries = []
            for p in self.folder.glob("*-*.bin"):
                try:
                    st = p.stat()
                except OSError:
                    continue
                entries.append((st.st_mtime, st.st_size, p))
        except OSError:
            return
        total = sum(s for _, s, _ in entries)
        for _, size, p in sorted(entries, key=lambda e: e[0]):
            if total <= self.max_bytes:
                break
            try:
                p.unlink()
                total -= size
            except OSError:
                pass


def _encode(arrays: dict, meta: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, __meta__=np.frombuffer(json.dumps(meta, sort_keys=True).encode(), np.uint8),
             **{k: np.ascontiguousarray(v) for k, v in arrays.items()})
    return buf.getvalue()


def _decode(data: bytes, kind: str, key: str) -> dict:
    """The arrays of an entry; ValueError (the reason) when it fails verification."""
    n = len(MAGIC)
    if len(data) < n + 32 or data[:n] != MAGIC:
        raise ValueError("is not a whitted cache file (bad header)")
    payload = data[n + 32:]
    if hashlib.sha256(payload).digest() != data[n:n + 32]:
        raise ValueError("is corrupt (checksum mismatch)")
    try:
        with np.load(io.BytesIO(payload), allow_pickle=False) as z:
            out = {k: z[k] for k in z.files}
        meta = json.loads(out.pop("__meta__").tobytes().decode())
    except Exception as e:             # a payload numpy cannot read
        raise ValueError(f"is unreadable ({type(e).__name__})") from None
    if meta.get("kind") != kind or meta.get("key") != key:
        raise ValueError("belongs to another key (foreign entry)")
    out["meta"] = meta
    return out
