"""A disk cache of built trees (and other arrays), keyed by their content.

An entry is one file ``<folder>/<kind>-<key>.bin``: the magic line ``MAGIC``, the length
(8 bytes, little-endian) and SHA-256 (32 bytes) of a JSON header, the header, then each
array's bytes at a multiple of ``ALIGN`` bytes from the start of the file. The header
repeats the kind and the key, holds the caller's ``meta`` and, per array, its name,
dtype, shape, offset and ``checksum``, and the file's size. The key (``content_key``)
hashes the input bytes, the producer and its parameters and ``code_version()`` (the
source text of the modules that write the layout), so any change of triangles, builder,
parameter or code misses.

- read without copies: the arrays of a hit are views of a private memory map of the
  file (writable: a write changes the process's pages, never the file), each at an
  ``ALIGN``-byte boundary;
- written atomically (``renderer.outputs.atomic_path``): a reader sees a whole entry or
  none; two processes writing one key both write the same bytes and the last rename wins;
- verified on read: a short, corrupt or foreign entry (bad magic, header digest, size,
  key, array checksum) is never trusted: ``get`` warns once (``CacheWarning``), removes it
  where it can and returns None, so the caller rebuilds. An array's ``checksum`` is two
  position-weighted sums of its 32-bit words (blocks of ``BLOCK`` words weighted by their
  index, and the words' places in a block by theirs): additions only, cheaper than
  SHA-256, and any change of one or two words (flipped bits, a swap) changes it, as does
  a zeroed or torn page; the header that names the arrays is covered by SHA-256; large
  arrays are summed in slices on threads (``checksums``), which also map the file's pages
  as they read them;
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
import json
import mmap
import os
import sys
import threading
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..cache_key import CODE_MODULES, CacheWarning, code_version, content_key
from ..outputs import OutputError, atomic_path

__all__ = ["ALIGN", "CODE_MODULES", "MAGIC", "MAX_BYTES", "CacheWarning", "TreeCache",
           "checksum", "checksums", "code_version", "content_key", "default_folder"]

MAGIC = b"whitted-cache 2\n"
#: Default bound on the folder's size (bytes).
MAX_BYTES = 2 << 30
#: Byte alignment of every array in an entry file (and so of the arrays a hit gives).
ALIGN = 64
#: 32-bit words per block of ``checksum``.
BLOCK = 1024
_PREFIX = len(MAGIC) + 8 + 32


def default_folder() -> Path:
    """``$WHITTED_CACHE``, else the user cache folder's ``whitted``."""
    env = os.environ.get("WHITTED_CACHE")
    if env:
        return Path(env).expanduser()
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "whitted"
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "whitted"


def checksum(a: np.ndarray) -> list[int]:
    """``[s_blocks, s_places]`` of the bytes of ``a`` (C order) read as little-endian
    32-bit words (the last one zero-padded), in blocks of ``BLOCK`` words: each block's
    sum weighted by ``2 b + 1`` (``b`` its index) and each place's sum over the blocks
    weighted by ``2 k + 1`` (``k`` the place in a block), mod 2^64. The words are summed
    exactly (64-bit sums of 32-bit words) and the weights are odd, so a change of any one
    or two words (two bits flipped anywhere, a swap of two words) changes the pair.
    Arrays of more than ``SPLIT_WORDS`` words are summed in slices of blocks on threads
    (numpy releases the interpreter lock; the sums, mod 2^64, are the same)."""
    return checksums([a])[0]


#: Words above which ``checksums`` sums an array in slices on threads.
SPLIT_WORDS = 1 << 20
_POOL: dict = {}


def _pool():
    """The checksums' threads, one pool per process (a forked child makes its own: the
    parent's threads are not in it)."""
    pid = os.getpid()
    if _POOL.get("pid") != pid:
        from concurrent.futures import ThreadPoolExecutor
        _POOL.update(pid=pid, pool=ThreadPoolExecutor(max(1, min(16, os.cpu_count() or 1)),
                                                      thread_name_prefix="cache checksum"))
    return _POOL["pool"]


def _words(a: np.ndarray) -> np.ndarray:
    b = np.ascontiguousarray(a).reshape(-1).view(np.uint8)
    n = b.size // 4
    words = b[:n * 4].view("<u4")
    if b.size > n * 4:
        last = np.zeros(4, np.uint8)
        last[:b.size - n * 4] = b[n * 4:]
        words = np.concatenate([words, last.view("<u4")])
    return words


def _block_sums(blocks: np.ndarray, first: int) -> tuple[int, np.ndarray]:
    """The blocks' part of ``checksum``: the weighted sum of their row sums (block
    ``first + i`` weighted by ``2 (first + i) + 1``) and their place sums, mod 2^64."""
    rows = np.add.reduce(blocks, axis=1, dtype=np.uint64)
    odd = np.arange(first, first + rows.size, dtype=np.uint64) * np.uint64(2) + np.uint64(1)
    with np.errstate(over="ignore"):
        return (int(np.add.reduce(rows * odd, dtype=np.uint64)),
                np.add.reduce(blocks, axis=0, dtype=np.uint64))


def checksums(arrays: list) -> list[list[int]]:
    """``checksum`` of each array of ``arrays``, large ones in slices on threads."""
    words = [_words(a) for a in arrays]
    jobs = []                      # (array index, first block, blocks)
    for i, w in enumerate(words):
        nb = w.size // BLOCK
        step = max(1, SPLIT_WORDS // BLOCK)
        for b0 in range(0, nb, step):
            jobs.append((i, b0, w[b0 * BLOCK:min(nb, b0 + step) * BLOCK].reshape(-1, BLOCK)))
    if len(jobs) > 1:
        parts = list(_pool().map(lambda j: _block_sums(j[2], j[1]), jobs))
    else:
        parts = [_block_sums(j[2], j[1]) for j in jobs]
    mask = (1 << 64) - 1
    out = []
    for i, w in enumerate(words):
        m = w.size // BLOCK * BLOCK
        mine = [p for j, p in zip(jobs, parts) if j[0] == i]
        rows = sum(p[0] for p in mine)
        places = np.zeros(BLOCK, np.uint64)
        with np.errstate(over="ignore"):
            for _, p in mine:
                places += p
        tail = w[m:]
        rows += (2 * (m // BLOCK) + 1) * int(np.add.reduce(tail, dtype=np.uint64))
        places[:tail.size] += tail
        odd = np.arange(BLOCK, dtype=np.uint64) * np.uint64(2) + np.uint64(1)
        with np.errstate(over="ignore"):
            out.append([rows & mask, int(np.add.reduce(places * odd, dtype=np.uint64))])
    return out


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
            f = open(p, "rb")
        except (FileNotFoundError, NotADirectoryError):
            self.misses += 1
            return None
        except OSError as e:
            self.misses += 1
            warnings.warn(f"{p}: cache entry unreadable ({e.strerror or e}); rebuilding",
                          CacheWarning, stacklevel=2)
            return None
        try:
            with f:
                out = _read(f, kind, key)
        except (ValueError, OSError) as e:
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

    def put_made(self, kind: str, key: str, make) -> bool:
        """``put`` of the entry ``make()`` answers (``(arrays, meta)``): with
        ``background``, ``make`` runs on the writer thread too, so host work that only the
        entry needs stays off the caller's path (it must not use Dr.Jit). An entry that
        ``make`` fails to make (it raises) is not written: one ``CacheWarning``, False."""
        if self.background:
            th = threading.Thread(target=self._write_made, args=(kind, key, make),
                                  name=f"cache {kind}")
            th.start()
            self._pending.append(th)
            return True
        return self._write_made(kind, key, make)

    def _write_made(self, kind: str, key: str, make) -> bool:
        try:
            arrays, meta = make()
        except Exception as e:           # a cache entry is never worth a failed render
            warnings.warn(f"{self.folder}: {kind} cache entry not made ({type(e).__name__}: "
                          f"{e}); working without it", CacheWarning, stacklevel=2)
            return False
        return self._write(kind, key, arrays, meta)

    def flush(self) -> None:
        """Wait for the writes ``put`` handed to threads (``background``)."""
        while self._pending:
            self._pending.pop().join()

    def _write(self, kind: str, key: str, arrays: dict, meta: dict | None) -> bool:
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with atomic_path(self.path(kind, key), overwrite=True) as tmp:
                with open(tmp, "wb") as f:
                    _write_entry(f, kind, key, arrays, dict(meta or {}))
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


def _aligned(n: int) -> int:
    return -(-n // ALIGN) * ALIGN


def _write_entry(f, kind: str, key: str, arrays: dict, meta: dict) -> None:
    """One entry (the module docstring's layout) to the open binary file ``f``."""
    arrays = {k: np.ascontiguousarray(v) for k, v in arrays.items()}
    table, offset = [], 0
    for (name, a), check in zip(arrays.items(), checksums(list(arrays.values()))):
        table.append([name, a.dtype.str, list(a.shape), offset, a.nbytes, check])
        offset = _aligned(offset + a.nbytes)
    head = {"kind": kind, "key": key, "meta": meta, "arrays": table}
    # the file size closes the header; its digits do not move the data start by more
    # than the alignment absorbs, so it is computed for the longest it can be
    text = json.dumps(dict(head, size=0), sort_keys=True).encode()
    start = _aligned(_PREFIX + len(text) + 24)
    text = json.dumps(dict(head, size=start + offset), sort_keys=True).encode()
    text += b" " * (start - _PREFIX - len(text))
    f.write(MAGIC + len(text).to_bytes(8, "little") + hashlib.sha256(text).digest() + text)
    for a in arrays.values():
        f.write(a.reshape(-1).view(np.uint8).data)
        f.write(b"\0" * (_aligned(a.nbytes) - a.nbytes))


def _map(f, size: int):
    """A private, writable memory map of the whole file ``f``. Its pages are mapped as
    they are first read (the checksums' threads read them in parallel): a private
    writable map populated up front would copy every page."""
    return mmap.mmap(f.fileno(), size, access=mmap.ACCESS_COPY)


def _read(f, kind: str, key: str) -> dict:
    """The arrays of the entry in the open file ``f``; ValueError (the reason) when it
    fails verification."""
    n = len(MAGIC)
    prefix = f.read(_PREFIX)
    if len(prefix) < _PREFIX or prefix[:n] != MAGIC:
        raise ValueError("is not a whitted cache file (bad header)")
    size = os.fstat(f.fileno()).st_size
    length = int.from_bytes(prefix[n:n + 8], "little")
    if _PREFIX + length > size:
        raise ValueError("is truncated")
    text = f.read(length)
    if hashlib.sha256(text).digest() != prefix[n + 8:]:
        raise ValueError("is corrupt (header checksum mismatch)")
    try:
        head = json.loads(text)
        if head.get("kind") != kind or head.get("key") != key:
            raise ValueError("belongs to another key (foreign entry)")
        if head["size"] != size:
            raise ValueError("is truncated" if size < head["size"] else "has trailing bytes")
        start = _aligned(_PREFIX + length)
        table = [(str(name), np.dtype(dt), tuple(int(s) for s in shape), int(off),
                  int(nb), [int(c) for c in check])
                 for name, dt, shape, off, nb, check in head["arrays"]]
        meta = dict(head["meta"])
    except ValueError:
        raise
    except (KeyError, TypeError, AttributeError) as e:
        raise ValueError(f"is unreadable ({type(e).__name__})") from None
    mm = _map(f, size)
    out = {}
    for name, dt, shape, off, nb, _check in table:
        count = int(np.prod(shape, dtype=np.int64))
        if (dt.hasobject or count * dt.itemsize != nb or off % ALIGN
                or start + off + nb > size):
            raise ValueError(f"is unreadable (array {name!r} out of place)")
        a = (np.frombuffer(mm, dt, count, start + off) if count else np.zeros(0, dt))
        out[name] = a.reshape(shape)
    for (name, *_, check), got in zip(table, checksums([out[t[0]] for t in table])):
        if got != check:
            raise ValueError(f"is corrupt (checksum mismatch in {name!r})")
    out["meta"] = meta
    return out
