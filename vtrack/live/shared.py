"""Shared-memory transport of large frames between the live pipeline's processes.

A replay reader in a child process used to pickle every decoded frame into a pipe (a 640x480 depth image,
four 320x240 RGB tactile images per 1/60 s: ~70 MB/s), the tracker's process unpickled it, and the touch
worker pickled each tactile image again into its helper process: each byte crossed two pipes (64 KB at a
time, a context switch each) and was copied ~6 times. With a :class:`FrameRing` the reader decodes into a
slot of a ring buffer in shared memory (a file in ``/dev/shm``, mapped by every process), and only the slot
number travels; the tracker's process and the helper read the frame where it lies.

A slot is reused ``slots`` frames of its stream later. Each slot carries the sequence number of the frame
written into it (-1 while being written), so a reader checks after reading (a seqlock): a frame overwritten
meanwhile (its consumer fell more than ``slots`` frames behind) raises :class:`FrameOverwritten`, which the
pipeline counts as a dropped frame, never as silently wrong data.
"""

from __future__ import annotations

import os
import tempfile
import uuid
import weakref
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

#: fields of at least this many bytes per frame go through the ring; smaller ones (joints) are pickled
MIN_SHARED_BYTES = 16 * 1024


class FrameOverwritten(RuntimeError):
    """A shared frame was overwritten by a newer one before its consumer had read it (counted as dropped)."""


@dataclass(frozen=True)
class RingLayout:
    """Where each stream's slots lie in the ring file (picklable: sent to the child processes).

    ``fields[stream][field] = (offset, shape, dtype)`` of slot 0 (slot ``j`` at ``offset + j * nbytes``);
    ``seq[stream]`` = offset of the stream's ``int64[slots]`` sequence numbers."""

    path: str
    slots: int
    fields: dict[str, dict[str, tuple[int, tuple[int, ...], str]]]
    seq: dict[str, int]
    nbytes: int


@dataclass(frozen=True)
class SharedSlot:
    """A reference to one frame's field in a ring: enough for any process to map and check it."""

    path: str
    offset: int
    shape: tuple[int, ...]
    dtype: str
    seq_offset: int
    seq: int

    def view(self) -> np.ndarray:
        """The field in place (no copy; valid until the slot is reused, see :meth:`check`)."""
        return np.ndarray(self.shape, np.dtype(self.dtype), buffer=_mapped(self.path), offset=self.offset)

    def check(self) -> None:
        """Raise :class:`FrameOverwritten` if the slot no longer holds this frame."""
        s = np.ndarray((), np.int64, buffer=_mapped(self.path), offset=self.seq_offset)
        if int(s) != self.seq:
            raise FrameOverwritten(f"frame {self.seq} overwritten in the shared ring")

    def read(self, fn: Callable[[np.ndarray], Any] = np.array) -> Any:
        """``fn(view)`` (default: a copy), checked afterwards: the result is the frame's or it raises."""
        out = fn(self.view())
        self.check()
        return out


_MAPS: dict[str, Any] = {}


def _mapped(path: str, populate: bool = False) -> Any:
    """The ring file mapped in this process (once per process and file). ``populate``: every page mapped at once
    (``MAP_POPULATE`` where the OS has it), for the process that writes every slot: one page-table pass before the
    replay's clock starts instead of a page fault per 4 KB page all through the first lap of the slots (a 5 s
    session's replay is mostly its first lap). A consumer maps lazily: it touches only its streams' slots."""
    mm = _MAPS.get(path)
    if mm is None:
        import mmap

        with open(path, "r+b") as f:
            size = os.fstat(f.fileno()).st_size
            flags = mmap.MAP_SHARED | (getattr(mmap, "MAP_POPULATE", 0) if populate else 0)
            m = mmap.mmap(f.fileno(), size, flags=flags, prot=mmap.PROT_READ | mmap.PROT_WRITE)
        mm = _MAPS[path] = np.frombuffer(m, np.uint8)
    return mm


def release_mapping(path: str) -> None:
    """Forget this process's mapping of a ring file (after its owner removed it)."""
    _MAPS.pop(path, None)


class FrameRing:
    """A ring of frame slots per stream in one shared file (:class:`RingLayout`).

    Created by the process that owns the replay (:meth:`create`, removed by :meth:`close`); the writer
    (reader process) and the consumers' processes map it by path."""

    def __init__(self, layout: RingLayout, writer: bool = True) -> None:
        self.layout = layout
        self.counts: dict[str, int] = {}
        # the writer (the replay's reader process) writes every slot: its whole mapping now, before the clock
        _mapped(layout.path, populate=writer)

    @classmethod
    def create(cls, shapes: Mapping[str, Mapping[str, tuple[tuple[int, ...], Any]]], slots: int) -> FrameRing:
        """A new ring for ``shapes[stream][field] = (frame shape, dtype)`` with ``slots`` slots per stream."""
        fields: dict[str, dict[str, tuple[int, tuple[int, ...], str]]] = {}
        seq: dict[str, int] = {}
        off = 0
        for stream, fs in shapes.items():
            seq[stream] = off
            off += 8 * slots
            fields[stream] = {}
            for f, (shape, dtype) in fs.items():
                dt = np.dtype(dtype)
                fields[stream][f] = (off, tuple(int(x) for x in shape), dt.str)
                off += slots * int(np.prod(shape, dtype=np.int64)) * dt.itemsize
                off = -(-off // 64) * 64  # cache-line aligned slots
        base = ring_dir(off)
        if base is None:
            raise OSError(f"no room for a {off / 1e6:.0f} MB frame ring in /dev/shm or the temporary directory")
        fd, path = tempfile.mkstemp(prefix=f"vtrack-live-{os.getpid()}-{uuid.uuid4().hex[:8]}-", dir=base)
        try:
            if hasattr(os, "posix_fallocate"):
                # the pages are allocated (and zeroed) now, before the replay's clock starts, not by the reader's
                # first write into each slot; a full /dev/shm fails here (OSError: the caller falls back to the
                # pipe) instead of killing the writer with SIGBUS later
                os.posix_fallocate(fd, 0, max(off, 8))
            else:
                os.ftruncate(fd, max(off, 8))
        except OSError:
            os.close(fd)
            os.unlink(path)
            raise
        os.close(fd)
        ring = cls(RingLayout(path, int(slots), fields, seq, off), writer=False)
        ring._finalizer = weakref.finalize(ring, _remove, path)  # also at exit or when dropped unclosed
        mm = _mapped(path)
        for o in seq.values():  # no frame in any slot yet
            np.ndarray((slots,), np.int64, buffer=mm, offset=o)[:] = -1
        return ring

    def slot_of(self, stream: str, field: str, seq: int) -> SharedSlot:
        off, shape, dt = self.layout.fields[stream][field]
        j = seq % self.layout.slots
        nb = int(np.prod(shape, dtype=np.int64)) * np.dtype(dt).itemsize
        return SharedSlot(self.layout.path, off + j * nb, shape, dt, self.layout.seq[stream] + 8 * j, seq)

    def write(self, stream: str, data: Mapping[str, np.ndarray]) -> tuple[int, dict[str, np.ndarray]]:
        """Copy ``data``'s ring fields into the stream's next slot; returns its sequence number and the
        fields that do not go through the ring (sent as they are)."""
        n = self.counts.get(stream, 0)
        self.counts[stream] = n + 1
        mm = _mapped(self.layout.path)
        j = n % self.layout.slots
        s = np.ndarray((), np.int64, buffer=mm, offset=self.layout.seq[stream] + 8 * j)
        s[...] = -1  # being written: a reader of the old frame in this slot fails its check from now on
        rest = {}
        for f, v in data.items():
            if f in self.layout.fields.get(stream, {}):
                self.slot_of(stream, f, n).view()[...] = v
            else:
                rest[f] = v
        s[...] = n
        return n, rest

    def slots(self, stream: str, seq: int) -> dict[str, SharedSlot]:
        """The ring fields of frame ``seq`` of ``stream``."""
        return {f: self.slot_of(stream, f, seq) for f in self.layout.fields.get(stream, {})}

    def close(self) -> None:
        """Remove the ring file (processes that still map it keep their mapping until they drop it)."""
        fin = getattr(self, "_finalizer", None)
        if fin is not None:
            fin()


def ring_dir(nbytes: int) -> str | None:
    """Where a ring of ``nbytes`` goes: ``/dev/shm`` (memory) if it has room for twice that (a container's
    /dev/shm is often 64 MB, and writing past a tmpfs's size kills the writer with SIGBUS), else the temporary
    directory (a file in the page cache), else None."""
    for d in ("/dev/shm", tempfile.gettempdir()):
        if os.path.isdir(d):
            st = os.statvfs(d)
            if st.f_bavail * st.f_frsize >= 2 * nbytes:
                return d
    return None


def _remove(path: str) -> None:
    release_mapping(path)
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def ring_shapes(reader: Any, streams: list[str], fields: Mapping[str, list[str]] | None) -> dict:
    """Per stream, the fields worth sharing (>= :data:`MIN_SHARED_BYTES` per frame): shape and dtype."""
    out: dict[str, dict[str, tuple[tuple[int, ...], Any]]] = {}
    for name in streams:
        s = reader[name]
        for f in (fields or {}).get(name) or list(s.fields):
            a = s.fields[f]
            shape = tuple(a.shape[1:])
            if int(np.prod(shape, dtype=np.int64)) * np.dtype(a.dtype).itemsize >= MIN_SHARED_BYTES:
                out.setdefault(name, {})[f] = (shape, a.dtype)
    return out
