"""Session format: a directory with a versioned JSON manifest and chunked, compressed Zarr v3 arrays.

Layout::

    SESSION/
      manifest.json          # format, version, scene, streams (fields, units, frames, rates), creation info
      data.zarr/             # Zarr v3 group
        <stream>/t           # (N,) float64 timestamps, seconds, strictly increasing
        <stream>/<field>     # (N, ...) per-frame arrays, chunked along time
      assets/                # small files (object mesh copy, calibration, ...)

A *stream* is one sensor (or ground-truth signal) sampled at its own timestamps, e.g.
``camera/cam0`` with fields ``rgb``, ``depth``, ``mask``; ``tactile/digit_index`` with ``image``;
``joints`` with ``q``; ``gt/object_pose`` with ``T_world_object``.

Crash safety: frames are written to the arrays first; only then the stream's committed frame
count (an attribute of the stream group, written atomically by Zarr's local store) is raised.
Readers only ever see committed frames, so killing a writer at any point leaves every flushed
frame readable and never exposes a half-written one. Arrays grow in blocks, so their shape may
exceed the committed count after a crash; the reader slices to the committed count.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from vtrack.errors import InputError
from vtrack.io.jsonio import write_json

FORMAT_NAME = "vtrack-session"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"
DATA = "data.zarr"
ASSETS = "assets"

#: Standard field names and their meaning (documentation; other fields are allowed).
STANDARD_FIELDS = {
    "rgb": "uint8 (H, W, 3) colour image",
    "depth": "uint16 (H, W) depth in units of the stream's depth_scale (m/unit), or float32 metres",
    "mask": "uint8 (H, W) object segmentation (1 = object)",
    "image": "uint8 (H, W, 3) tactile image (BGR as OpenCV reads it)",
    "height_mm": "float32 (H, W) ground-truth gel indentation height, mm",
    "contact": "uint8 (H, W) ground-truth contact mask",
    "q": "float64 (J,) joint positions, rad, order in the stream's joint_names",
    "T_world_object": "float64 (4, 4) object pose",
}


@dataclass
class FieldSpec:
    """Declaration of one per-frame array of a stream.

    Args:
        shape: per-frame shape (without the time axis).
        dtype: numpy dtype name.
        units: e.g. "m", "mm", "rad", "px", "uint16 depth units".
        chunk_frames: frames per chunk along time (1 for images; more for small vectors).
    """

    shape: tuple[int, ...]
    dtype: str
    units: str = ""
    chunk_frames: int | None = None

    def resolved_chunk(self) -> int:
        if self.chunk_frames:
            return int(self.chunk_frames)
        per_frame = int(np.prod(self.shape, dtype=np.int64)) * np.dtype(self.dtype).itemsize
        # Aim for chunks of ~1 MB, at least one frame.
        return int(max(1, min(1024, (1 << 20) // max(per_frame, 1))))


@dataclass
class StreamSpec:
    """Declaration of a stream: what it measures, in which frame, at which nominal rate."""

    kind: str
    fields: dict[str, FieldSpec]
    frame: str = ""
    rate_hz: float | None = None
    attrs: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {
            "kind": self.kind,
            "frame": self.frame,
            "rate_hz": self.rate_hz,
            "attrs": self.attrs,
            "fields": {
                k: {"shape": list(v.shape), "dtype": v.dtype, "units": v.units, "chunk_frames": v.resolved_chunk()}
                for k, v in self.fields.items()
            },
        }


#: Top-level entries a session folder may hold; anything else is user data that --force must not delete.
_SESSION_ENTRIES = {MANIFEST, DATA, ASSETS}


def check_replaceable(path: str | Path) -> None:
    """Raise unless ``path`` may be deleted to write a new session there (``overwrite=True`` / ``--force``).

    Only an empty directory, or a vtrack session (a ``manifest.json`` whose ``format`` is
    ``vtrack-session``, holding nothing but ``manifest.json``, ``data.zarr/``, ``assets/`` and the
    writer's own ``.manifest.json.*.tmp`` files) may be replaced: ``--force`` on a folder of
    user files must never delete them.

    Raises:
        InputError: ``path`` is a file, a symlink, a non-session folder or a session with extra files.
    """
    p = Path(path)
    if p.is_symlink() or not p.is_dir():
        raise InputError(
            "output path exists and is not a directory; refusing to replace it",
            path=p,
            expected="a vtrack session folder, an empty folder or a new path",
        )
    entries = [e.name for e in p.iterdir()]
    if not entries:
        return
    m = p / MANIFEST
    fmt = None
    if m.is_file():
        try:
            fmt = json.loads(m.read_text()).get("format")
        except Exception:  # unreadable/corrupt manifest: treat as not a session (refuse below)
            fmt = None
    if fmt != FORMAT_NAME:
        raise InputError(
            "output folder exists and is not a vtrack session; --force only replaces a session "
            "or an empty folder (nothing was deleted)",
            path=p,
            expected="a folder with a vtrack manifest.json",
            got=f"{len(entries)} entries, e.g. {sorted(entries)[:3]}",
        )
    extra = sorted(
        e for e in entries if e not in _SESSION_ENTRIES and not (e.startswith(f".{MANIFEST}.") and e.endswith(".tmp"))
    )
    if extra:
        raise InputError(
            f"session folder holds files that are not part of the session ({', '.join(extra[:5])}); "
            "refusing to delete them (move them away first)",
            path=p,
        )


class SessionWriter:
    """Append-only writer of a session directory, frame by frame.

    Use as a context manager; ``close()`` trims arrays and marks the manifest complete. A writer
    that dies before ``close()`` leaves a readable session holding every flushed frame.

    Args:
        path: session directory (created).
        scene: the scene (``Scene`` or its dict) embedded in the manifest.
        overwrite: replace an existing session directory.
        flush_every: commit after this many appended frames per stream (1 = every frame).
        info: extra creation info stored in the manifest (e.g. generator parameters).
    """

    def __init__(
        self,
        path: str | Path,
        scene: Any = None,
        *,
        overwrite: bool = False,
        flush_every: int = 1,
        info: dict | None = None,
    ) -> None:
        import zarr

        self.path = Path(path)
        if self.path.exists() or self.path.is_symlink():
            if not overwrite:
                raise InputError(
                    "session directory exists (pass overwrite=True / --force to replace it)", path=self.path
                )
            check_replaceable(self.path)
            shutil.rmtree(self.path)
        self.path.mkdir(parents=True)
        (self.path / ASSETS).mkdir()
        self.flush_every = max(1, int(flush_every))
        scene_dict = scene.to_dict() if hasattr(scene, "to_dict") else scene
        self.manifest: dict[str, Any] = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "complete": False,
            "created": {
                "time_unix": time.time(),
                "host": platform.node(),
                "vtrack_version": _vtrack_version(),
                **(info or {}),
            },
            "units": {"length": "m", "angle": "rad", "time": "s", "tactile_height": "mm"},
            "frames": {"world": "fixed world frame; all extrinsics are T_world_<frame>"},
            "scene": scene_dict,
            "streams": {},
            "assets": {},
        }
        self._root = zarr.open_group(str(self.path / DATA), mode="w", zarr_format=3)
        self._streams: dict[str, dict[str, Any]] = {}
        self._write_manifest()

    # -- declaration -------------------------------------------------------------------------
    def add_stream(self, name: str, spec: StreamSpec) -> None:
        """Declare a stream before appending to it."""
        import zarr

        if name in self._streams:
            raise InputError("stream declared twice", field=name)
        if not name or name.startswith("/") or ".." in name:
            raise InputError("invalid stream name", field=name, expected="like 'camera/cam0'")
        g = self._root.require_group(name)
        arrays = {}
        block = {}
        for fname, fs in {"t": FieldSpec((), "float64", "s", 1024), **spec.fields}.items():
            chunk = fs.resolved_chunk()
            # CRC32C over each compressed chunk lets readers tell corruption from data, and writing
            # all-fill chunks too means a missing chunk file is always damage (see verify_session).
            arrays[fname] = g.create_array(
                fname,
                shape=(0, *fs.shape),
                chunks=(chunk, *fs.shape),
                dtype=fs.dtype,
                fill_value=0,
                compressors=[zarr.codecs.ZstdCodec(level=3), zarr.codecs.Crc32cCodec()],
                config={"write_empty_chunks": True},
            )
            block[fname] = chunk
        g.attrs.update({"n_committed": 0, "kind": spec.kind, "all_chunks_written": True})
        self._streams[name] = {
            "spec": spec,
            "group": g,
            "arrays": arrays,
            "block": block,
            "buffer": [],
            "n": 0,
            "capacity": 0,
            "last_t": -np.inf,
        }
        self.manifest["streams"][name] = spec.to_json()
        self._write_manifest()

    def add_asset(self, src: str | Path, name: str | None = None, role: str = "") -> Path:
        """Copy a small file into ``assets/`` (e.g. the object mesh) and list it in the manifest."""
        src = Path(src)
        if not src.exists():
            raise InputError("asset file does not exist", path=src)
        dst = self.path / ASSETS / (name or src.name)
        shutil.copyfile(src, dst)
        self.manifest["assets"][dst.name] = {"role": role, "source": str(src)}
        self._write_manifest()
        return dst

    def set_info(self, **info: Any) -> None:
        """Add JSON-able entries to the manifest's ``created`` block."""
        self.manifest["created"].update(info)
        self._write_manifest()

    # -- appending ----------------------------------------------------------------------------
    def append(self, stream: str, t: float, **values: Any) -> None:
        """Append one frame at time ``t`` (s). Every declared field must be given.

        Raises:
            InputError: unknown stream/field, missing field, wrong shape, non-increasing time.
        """
        st = self._streams.get(stream)
        if st is None:
            raise InputError(
                "unknown stream (declare it with add_stream first)",
                field=stream,
                expected=f"one of {sorted(self._streams)}",
            )
        spec: StreamSpec = st["spec"]
        t = float(t)
        if not np.isfinite(t):
            raise InputError("timestamp is not finite", field=f"{stream}/t", got=t)
        if t <= st["last_t"]:
            raise InputError(
                "timestamps must be strictly increasing", field=f"{stream}/t", expected=f"> {st['last_t']}", got=t
            )
        missing = set(spec.fields) - set(values)
        extra = set(values) - set(spec.fields)
        if missing or extra:
            raise InputError(
                "fields do not match the stream declaration",
                field=stream,
                expected=f"fields {sorted(spec.fields)}",
                got=f"missing {sorted(missing)}, unknown {sorted(extra)}",
            )
        row = {"t": t}
        for k, v in values.items():
            fs = spec.fields[k]
            a = np.asarray(v)
            if a.shape != tuple(fs.shape):
                raise InputError("wrong shape", field=f"{stream}/{k}", expected=str(tuple(fs.shape)), got=a.shape)
            if np.dtype(fs.dtype).kind in "ui" and a.dtype.kind == "f":
                raise InputError(
                    "float data for an integer field (convert explicitly)",
                    field=f"{stream}/{k}",
                    expected=fs.dtype,
                    got=str(a.dtype),
                )
            row[k] = a.astype(fs.dtype, copy=False)
        st["buffer"].append(row)
        st["last_t"] = t
        if len(st["buffer"]) >= self.flush_every:
            self._flush_stream(stream)

    def flush(self) -> None:
        """Write and commit every buffered frame of every stream."""
        for name in self._streams:
            self._flush_stream(name)

    def _flush_stream(self, name: str) -> None:
        st = self._streams[name]
        buf = st["buffer"]
        if not buf:
            return
        n0, k = st["n"], len(buf)
        need = n0 + k
        if need > st["capacity"]:
            # Grow in whole chunks so metadata rewrites are rare.
            step = max(st["block"].values())
            cap = max(need, st["capacity"] + step)
            for arr in st["arrays"].values():
                arr.resize((cap, *arr.shape[1:]))
            st["capacity"] = cap
        for fname, arr in st["arrays"].items():
            arr[n0:need] = np.stack([r[fname] for r in buf])
        # Commit only after the data is on disk.
        st["group"].attrs["n_committed"] = need
        st["n"] = need
        st["buffer"] = []

    def __len__(self) -> int:
        return sum(s["n"] + len(s["buffer"]) for s in self._streams.values())

    def close(self) -> None:
        """Flush, trim arrays to their committed length and mark the session complete."""
        if getattr(self, "_closed", False):
            return
        self.flush()
        for st in self._streams.values():
            for arr in st["arrays"].values():
                if arr.shape[0] != st["n"]:
                    arr.resize((st["n"], *arr.shape[1:]))
        self.manifest["complete"] = True
        self.manifest["counts"] = {k: v["n"] for k, v in self._streams.items()}
        self._write_manifest()
        self._closed = True

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            # Keep what was flushed; the manifest stays "complete": false.
            self.flush()

    def _write_manifest(self) -> None:
        write_json(self.path / MANIFEST, self.manifest, indent=1, fsync=True)


def _vtrack_version() -> str:
    from vtrack import __version__

    return __version__


class CorruptDataError(InputError):
    """A committed chunk of a session array cannot be read (truncated, overwritten, checksum mismatch)."""


#: What readers do when a frame cannot be read: raise (default), skip the bad frames, or stop at the first.
OnCorrupt = Literal["raise", "skip", "stop"]
ON_CORRUPT_ENV = "VTRACK_ON_CORRUPT"


#: bytes a sequential one-frame read may decode ahead in one call (whole chunks)
PREFETCH_BYTES = 4 << 20


class FieldReader:
    """Lazy view of one field, limited to the committed frames (indexing reads from disk).

    Args:
        array: the Zarr array.
        n: committed frames visible through this reader.
        name: ``<stream>/<field>`` (for messages).
        path: the array's folder on disk (for messages).
        index: optional map from visible frame to stored frame (set when bad frames are skipped).

    Raises (on indexing):
        CorruptDataError: a chunk of the requested frames cannot be decoded; names the array and frame.
    """

    def __init__(
        self, array: Any, n: int, name: str, path: Path | None = None, index: np.ndarray | None = None
    ) -> None:
        self._a = array
        self.n = n
        self.name = name
        self.path = path
        self._index = index
        # Zarr decodes a whole chunk (several frames of a small image) for any frame in it, and each call costs
        # ~1 ms of async overhead: one-frame reads keep the last decoded chunk, so a sequential pass decodes
        # each chunk once (tactile images: 4 frames per chunk, 1.5 -> 0.4 ms per frame); in a sequential pass
        # (frame j right after frame j - 1) a read takes up to PREFETCH_BYTES of whole chunks in one call (a
        # depth image per chunk: one call per ~6 frames instead of one per frame).
        self._chunk = max(1, int(getattr(array, "chunks", (1,))[0] or 1)) if getattr(array, "ndim", 0) else 1
        per_frame = int(np.prod(array.shape[1:], dtype=np.int64)) * np.dtype(array.dtype).itemsize if self._chunk else 0
        self._block_chunks = max(1, PREFETCH_BYTES // max(per_frame * self._chunk, 1))
        self._cached: tuple[int, np.ndarray] | None = None
        self._last = -2  # the stored frame read last (sequential-pass detection)
        from vtrack.io.chunks import ChunkFiles

        # one-frame reads decode the chunk files themselves where the layout is vtrack's own (half the CPU of a
        # read through Zarr's event loop, the same arrays: vtrack.io.chunks)
        self._files = ChunkFiles.of(array) if self._chunk else None

    def _block(self, c0: int, c1: int) -> np.ndarray:
        """Stored frames ``c0..c1-1`` (``c0`` on a chunk boundary): from the chunk files, else through Zarr."""
        if self._files is not None:
            block = self._files.read(c0, c1)
            if block is not None:
                return block
        return np.asarray(self._a[c0:c1])

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.n, *self._a.shape[1:])

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(self._a.dtype)

    def __len__(self) -> int:
        return self.n

    def _read(self, sel: Any, frames: str) -> np.ndarray:
        try:
            return np.asarray(sel())
        except Exception as e:  # zstd / checksum / shape errors from a damaged chunk file
            raise CorruptDataError(
                f"cannot read frame {frames}: corrupt or truncated chunk "
                f"({type(e).__name__}: {str(e).splitlines()[0][:120] if str(e) else ''}); "
                "run 'vtrack session verify' for the full list",
                path=self.path,
                field=self.name,
            ) from None

    def __getitem__(self, idx: Any) -> np.ndarray:
        if isinstance(idx, (int, np.integer)):
            i = int(idx) + (self.n if idx < 0 else 0)
            if not 0 <= i < self.n:
                raise IndexError(f"{self.name}: frame {idx} out of range (0..{self.n - 1})")
            j = i if self._index is None else int(self._index[i])
            sequential, self._last = j == self._last + 1, j
            cached = self._cached
            if cached is not None and cached[0] <= j < cached[0] + len(cached[1]):
                return cached[1][j - cached[0]].copy()
            if self._chunk == 1 and not sequential:
                return self._read(lambda: self._block(j, j + 1)[0], str(j))
            c0 = j - j % self._chunk
            n = int(
                self._a.shape[0]
            )  # only stored frames that exist; frames past the committed ones are never returned
            c1 = min(c0 + self._chunk * (self._block_chunks if sequential else 1), n)
            try:
                block = self._read(lambda: self._block(c0, c1), f"{c0}..{c1 - 1}")
            except CorruptDataError:
                if c1 - c0 <= self._chunk:
                    raise
                # a damaged chunk further on (its frames skipped or reported when reached): this chunk alone
                c1 = min(c0 + self._chunk, n)
                block = self._read(lambda: self._block(c0, c1), f"{c0}..{c1 - 1}")
            self._cached = cached = (c0, block)
            return cached[1][j - c0].copy()
        if isinstance(idx, slice):
            r = range(*idx.indices(self.n))
            if self._index is None and r.step == 1 and len(r) and self._files is not None:
                c0 = r.start - r.start % self._chunk  # whole chunks are decoded either way (Zarr too)
                return self._read(lambda: self._block(c0, r.stop)[r.start - c0 :], f"{r.start}..{r.stop - 1}")
            if self._index is None:
                return self._read(
                    lambda: self._a[slice(r.start, r.stop, r.step)], f"{r.start}..{r.stop - 1}" if len(r) else "(none)"
                )
            idx = np.arange(r.start, r.stop, r.step, dtype=np.int64)
        ids = np.asarray(idx)
        if ids.dtype == bool:
            ids = np.nonzero(ids)[0]
        if ids.size and (ids.min() < -self.n or ids.max() >= self.n):
            raise IndexError(f"{self.name}: frame index out of range (0..{self.n - 1})")
        ids = np.where(ids < 0, ids + self.n, ids)
        if self._index is not None:
            ids = self._index[ids]
        if ids.size == 0:
            return np.zeros((0, *self._a.shape[1:]), dtype=self._a.dtype)
        return self._read(lambda: self._a.get_orthogonal_selection((ids,)), f"{int(ids.min())}..{int(ids.max())}")

    def all(self) -> np.ndarray:
        return self[:]


class StreamReader:
    """Committed frames of one stream with time-synchronised access."""

    def __init__(
        self, name: str, group: Any, meta: dict, n: int, path: Path | None = None, index: np.ndarray | None = None
    ) -> None:
        self.name = name
        self.meta = meta
        self.kind: str = meta.get("kind", "")
        self.frame: str = meta.get("frame", "")
        self.rate_hz = meta.get("rate_hz")
        self.attrs: dict = meta.get("attrs", {})
        self.n = n
        self._group = group
        self.path = path
        t_reader = FieldReader(group["t"], n, f"{name}/t", None if path is None else path / "t")
        t = np.asarray(t_reader[:], dtype=np.float64)
        self.t = t if index is None else t[index]
        if index is not None:
            self.n = len(index)
        self.fields = {
            k: FieldReader(group[k], self.n, f"{name}/{k}", None if path is None else path / k, index)
            for k in meta["fields"]
        }

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, field: str) -> FieldReader:
        try:
            return self.fields[field]
        except KeyError:
            raise InputError(
                "no such field", field=f"{self.name}/{field}", expected=f"one of {sorted(self.fields)}"
            ) from None

    def frame_at(self, i: int) -> dict[str, np.ndarray]:
        """All fields of frame ``i`` as a dict (plus ``t``)."""
        out = {k: f[i] for k, f in self.fields.items()}
        out["t"] = self.t[i]
        return out

    def index_at(self, times: float | Sequence[float] | np.ndarray) -> np.ndarray:
        """Index of the nearest frame for each query time (clamped to the stream's range)."""
        if self.n == 0:
            raise InputError("stream has no frames", field=self.name)
        q = np.atleast_1d(np.asarray(times, dtype=np.float64))
        j = np.clip(np.searchsorted(self.t, q), 1, max(self.n - 1, 1))
        if self.n == 1:
            return np.zeros(q.shape, dtype=np.int64)
        left = self.t[j - 1]
        right = self.t[j]
        return np.where(np.abs(q - left) <= np.abs(right - q), j - 1, j).astype(np.int64)

    def sample(
        self, field: str, times: float | Sequence[float] | np.ndarray, mode: Literal["nearest", "linear"] = "nearest"
    ) -> np.ndarray:
        """Values of ``field`` at query times.

        ``nearest`` picks the closest frame; ``linear`` interpolates numeric fields between the
        two bracketing frames (4x4 rigid transforms are interpolated on SE(3): slerp + lerp).
        Query times outside the stream's range are clamped to its first/last frame.
        """
        f = self[field]
        q = np.atleast_1d(np.asarray(times, dtype=np.float64))
        if not np.all(np.isfinite(q)):
            raise InputError("query times must be finite", field=f"{self.name}/{field}")
        if mode == "nearest" or self.n == 1:
            return f[self.index_at(q)]
        if mode != "linear":
            raise InputError("unknown sampling mode", field="mode", expected="nearest|linear", got=mode)
        qc = np.clip(q, self.t[0], self.t[-1])
        j = np.clip(np.searchsorted(self.t, qc, side="right"), 1, self.n - 1)
        t0, t1 = self.t[j - 1], self.t[j]
        alpha = np.clip((qc - t0) / np.maximum(t1 - t0, 1e-12), 0.0, 1.0)
        a, b = f[j - 1].astype(np.float64), f[j].astype(np.float64)
        if a.shape[1:] == (4, 4):
            from vtrack.geometry.se3 import interpolate

            return interpolate(a, b, alpha)
        w = alpha.reshape((-1,) + (1,) * (a.ndim - 1))
        return (1.0 - w) * a + w * b


class SessionReader:
    """Read a session directory lazily; validates the manifest and every stream on open.

    Raises:
        InputError: missing or corrupt manifest, unsupported version, missing arrays,
            mismatched lengths or non-increasing timestamps (the message names the file/stream).
    """

    def __init__(self, path: str | Path, on_corrupt: OnCorrupt | None = None) -> None:
        import zarr

        self.path = Path(path)
        policy = on_corrupt or os.environ.get(ON_CORRUPT_ENV) or "raise"
        if policy not in ("raise", "skip", "stop"):
            raise InputError(
                "unknown corrupt-frame policy",
                field=f"on_corrupt / ${ON_CORRUPT_ENV}",
                expected="raise, skip or stop",
                got=policy,
            )
        self.on_corrupt: str = policy
        mpath = self.path / MANIFEST
        if not self.path.is_dir():
            raise InputError("session directory does not exist", path=self.path)
        if not mpath.exists():
            raise InputError("not a vtrack session (no manifest.json)", path=self.path)
        try:
            self.manifest = json.loads(mpath.read_text())
        except json.JSONDecodeError as e:
            raise InputError(f"corrupt manifest (JSON error at line {e.lineno}: {e.msg})", path=mpath) from None
        except UnicodeDecodeError:
            raise InputError("corrupt manifest (not UTF-8 text)", path=mpath) from None
        if not isinstance(self.manifest, dict):
            raise InputError("corrupt manifest", path=mpath, expected="a JSON object", got=type(self.manifest).__name__)
        if self.manifest.get("format") != FORMAT_NAME:
            raise InputError(
                "not a vtrack session manifest",
                path=mpath,
                field="format",
                expected=FORMAT_NAME,
                got=self.manifest.get("format"),
            )
        version = self.manifest.get("version")
        if not isinstance(version, int) or version > FORMAT_VERSION:
            raise InputError(
                "unsupported session format version",
                path=mpath,
                field="version",
                expected=f"<= {FORMAT_VERSION}",
                got=version,
            )
        streams = self.manifest.get("streams")
        if not isinstance(streams, dict):
            raise InputError("manifest has no stream table", path=mpath, field="streams", expected="a mapping")
        self.complete = bool(self.manifest.get("complete"))
        try:
            self._root = zarr.open_group(str(self.path / DATA), mode="r", zarr_format=3)
        except Exception as e:  # zarr raises several types for missing/corrupt stores
            raise InputError(f"cannot open the array store ({type(e).__name__}: {e})", path=self.path / DATA) from None
        self.streams: dict[str, StreamReader] = {}
        for name, meta in streams.items():
            self.streams[name] = self._open_stream(name, meta)
        #: frames hidden by ``on_corrupt`` ("skip"/"stop"): stream -> stored frame indices
        self.dropped_frames: dict[str, list[int]] = {}
        if self.on_corrupt != "raise":
            self._drop_bad_frames()

    def _drop_bad_frames(self) -> None:
        """Read every chunk once and hide the unreadable frames (all fields of a frame go together)."""
        for problem in verify_session(self):
            if problem.stream is None or problem.frames is None:
                continue
            self.dropped_frames.setdefault(problem.stream, []).extend(range(*problem.frames))
        for name, bad_list in self.dropped_frames.items():
            st = self.streams[name]
            bad = np.zeros(st.n, dtype=bool)
            bad[[b for b in bad_list if b < st.n]] = True
            if self.on_corrupt == "stop":
                first = int(np.argmax(bad)) if bad.any() else st.n
                keep = np.arange(first)
            else:
                keep = np.nonzero(~bad)[0]
            self.dropped_frames[name] = sorted(set(range(st.n)) - set(keep.tolist()))
            self.streams[name] = StreamReader(name, st._group, st.meta, st.n, st.path, keep)

    def _open_stream(self, name: str, meta: dict) -> StreamReader:
        where = self.path / DATA / name
        mpath = self.path / MANIFEST
        # The manifest is user-editable JSON: check the stream entry's structure before using it.
        if not isinstance(meta, dict):
            raise InputError(
                "stream entry must be an object", path=mpath, field=f"streams.{name}", got=type(meta).__name__
            )
        fields = meta.get("fields")
        if not isinstance(fields, dict) or not all(
            isinstance(f, dict) and isinstance(f.get("shape"), list) for f in fields.values()
        ):
            raise InputError(
                "stream fields must map names to {shape: [...], dtype: ...}",
                path=mpath,
                field=f"streams.{name}.fields",
                got=type(fields).__name__,
            )
        for key, typ in (("kind", str), ("frame", str), ("attrs", dict)):
            if key in meta and not isinstance(meta[key], typ):
                raise InputError(
                    f"must be a {typ.__name__}", path=mpath, field=f"streams.{name}.{key}", got=type(meta[key]).__name__
                )
        try:
            g = self._root[name]
            n_raw = g.attrs.get("n_committed", -1)
            if isinstance(n_raw, bool) or not isinstance(n_raw, int):
                raise InputError(
                    f"committed frame count is not an integer (got {n_raw!r})", path=where, field="n_committed"
                )
            n = int(n_raw)
        except InputError:
            raise
        except Exception as e:
            raise InputError(f"stream is missing or unreadable ({type(e).__name__})", path=where) from None
        if n < 0:
            raise InputError("stream has no committed frame count", path=where, field="n_committed")
        for fname in ["t", *meta.get("fields", {})]:
            try:
                arr = g[fname]
            except Exception:
                raise InputError("array listed in the manifest is missing", path=where / fname) from None
            if arr.shape[0] < n:
                raise InputError(
                    "array is shorter than the committed frame count",
                    path=where / fname,
                    expected=f">= {n} frames",
                    got=arr.shape[0],
                )
            decl = meta["fields"].get(fname) if fname != "t" else None
            if decl is not None and list(arr.shape[1:]) != list(decl["shape"]):
                raise InputError(
                    "array shape differs from the manifest",
                    path=where / fname,
                    expected=str(decl["shape"]),
                    got=list(arr.shape[1:]),
                )
        try:
            sr = StreamReader(name, g, meta, n, where)
        except CorruptDataError:
            if self.on_corrupt == "raise":
                raise
            raise InputError(
                "timestamps of the stream are unreadable (corrupt chunk); no frame can be skipped safely",
                path=where / "t",
            ) from None
        if n > 1:
            bad = np.nonzero(np.diff(sr.t) <= 0)[0]
            if bad.size:
                raise InputError(f"timestamps not strictly increasing at frame {int(bad[0]) + 1}", path=where / "t")
        if n and not np.all(np.isfinite(sr.t)):
            raise InputError("non-finite timestamps", path=where / "t")
        return sr

    # -- access -----------------------------------------------------------------------------
    def __contains__(self, name: str) -> bool:
        return name in self.streams

    def __getitem__(self, name: str) -> StreamReader:
        try:
            return self.streams[name]
        except KeyError:
            raise InputError(
                "no such stream in the session", path=self.path, field=name, expected=f"one of {sorted(self.streams)}"
            ) from None

    def streams_of_kind(self, kind: str) -> dict[str, StreamReader]:
        return {k: s for k, s in self.streams.items() if s.kind == kind}

    @property
    def scene_dict(self) -> dict | None:
        return self.manifest.get("scene")

    def scene(self, check_files: bool = False):
        """The embedded scene as a validated :class:`~vtrack.scene.schema.Scene`."""
        from vtrack.scene.load import scene_from_dict

        if self.scene_dict is None:
            raise InputError("session has no embedded scene", path=self.path / MANIFEST, field="scene")
        return scene_from_dict(
            self.scene_dict, base_dir=self.path, source=self.path / MANIFEST, check_files=check_files
        )

    def asset(self, name: str) -> Path:
        p = self.path / ASSETS / name
        if not p.exists():
            raise InputError("asset missing from the session", path=p)
        return p

    @property
    def duration(self) -> float:
        ts = [s.t for s in self.streams.values() if s.n]
        if not ts:
            return 0.0
        return float(max(t[-1] for t in ts) - min(t[0] for t in ts))

    def summary(self) -> dict[str, Any]:
        """Per-stream frame counts, time span and rates (JSON-able)."""
        out = {}
        for k, s in self.streams.items():
            span = float(s.t[-1] - s.t[0]) if s.n > 1 else 0.0
            out[k] = {
                "kind": s.kind,
                "frames": s.n,
                "t0": float(s.t[0]) if s.n else None,
                "duration_s": span,
                "rate_hz_measured": (s.n - 1) / span if span > 0 else None,
                "fields": {f: list(fr.shape[1:]) for f, fr in s.fields.items()},
            }
        return out


def is_complete(path: str | Path) -> bool:
    """True when ``path`` holds a session whose writer finished (manifest parses and says ``complete``);
    False for a missing, partial (crashed writer) or unreadable one. Cheap: reads only the manifest."""
    try:
        return bool(json.loads((Path(path) / MANIFEST).read_text()).get("complete"))
    except (OSError, ValueError, AttributeError):
        return False


def open_session(path: str | Path, on_corrupt: OnCorrupt | None = None) -> SessionReader:
    """Open and validate a session directory.

    Args:
        path: session folder.
        on_corrupt: what to do with frames whose chunks cannot be read: ``"raise"`` (default; reading
            them raises :class:`CorruptDataError`), ``"skip"`` (hide them) or ``"stop"`` (hide every
            frame from the first bad one on). ``skip``/``stop`` read every chunk once at open. Default
            from ``$VTRACK_ON_CORRUPT`` (set by ``vtrack --on-corrupt``), else ``raise``.
    """
    return SessionReader(path, on_corrupt=on_corrupt)


@dataclass
class ChunkProblem:
    """One damaged piece of a session found by :func:`verify_session`.

    ``frames`` is the half-open stored-frame range ``[start, stop)`` the chunk covers (None when the
    problem is not a chunk).
    """

    path: Path
    stream: str | None
    field: str | None
    frames: tuple[int, int] | None
    message: str

    def __str__(self) -> str:
        where = f"frames {self.frames[0]}..{self.frames[1] - 1}: " if self.frames else ""
        return f"{self.path}: {where}{self.message}"


def verify_session(session: str | Path | SessionReader) -> list[ChunkProblem]:
    """Read every committed chunk of every array of a session; return what is damaged.

    Checks: each chunk decodes (Zstd) and matches its stored CRC32C checksum (sessions written since
    checksums were added); for such sessions a missing chunk file is damage too (every chunk is
    written, even all-zero ones). Older sessions' missing chunks read as zeros and cannot be told
    from data. Memory: one chunk at a time.

    Raises:
        InputError: the session cannot be opened at all (manifest, store, timestamps).
    """
    r = session if isinstance(session, SessionReader) else SessionReader(session, on_corrupt="raise")
    problems: list[ChunkProblem] = []
    for name, st in r.streams.items():
        g = st._group
        n = int(g.attrs.get("n_committed", st.n))
        strict = bool(g.attrs.get("all_chunks_written", False))
        for fname in ["t", *st.meta.get("fields", {})]:
            arr = g[fname]
            where = r.path / DATA / name / fname
            step = int(arr.chunks[0]) or 1
            for a in range(0, n, step):
                b = min(a + step, n)
                if strict:
                    key = "/".join(["c", str(a // step), *["0"] * (arr.ndim - 1)])
                    if not (where / key).is_file():
                        problems.append(ChunkProblem(where, name, fname, (a, b), f"chunk file {key} is missing"))
                        continue
                try:
                    arr[a:b]
                except Exception as e:
                    msg = str(e).splitlines()[0][:120] if str(e) else ""
                    problems.append(
                        ChunkProblem(where, name, fname, (a, b), f"corrupt chunk ({type(e).__name__}: {msg})")
                    )
    return problems


def copy_streams(reader: SessionReader, writer: SessionWriter, names: Iterable[str] | None = None) -> None:
    """Copy whole streams from one session into another (used by converters and tests)."""
    for name in names or reader.streams:
        s = reader[name]
        meta = s.meta
        spec = StreamSpec(
            kind=meta["kind"],
            frame=meta.get("frame", ""),
            rate_hz=meta.get("rate_hz"),
            attrs=meta.get("attrs", {}),
            fields={
                k: FieldSpec(tuple(v["shape"]), v["dtype"], v.get("units", ""), v.get("chunk_frames"))
                for k, v in meta["fields"].items()
            },
        )
        writer.add_stream(name, spec)
        for i in range(s.n):
            fr = s.frame_at(i)
            t = fr.pop("t")
            writer.append(name, t, **fr)
