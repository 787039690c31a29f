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


def _atomic_write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


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

    def __init__(self, path: str | Path, scene: Any = None, *, overwrite: bool = False, flush_every: int = 1,
                 info: dict | None = None) -> None:
        import zarr

        self.path = Path(path)
        if self.path.exists():
            if not overwrite:
                raise InputError("session directory exists (pass overwrite=True / --force to replace it)",
                                 path=self.path)
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
            arrays[fname] = g.create_array(
                fname, shape=(0, *fs.shape), chunks=(chunk, *fs.shape), dtype=fs.dtype,
                fill_value=0, compressors=zarr.codecs.ZstdCodec(level=3),
            )
            block[fname] = chunk
        g.attrs.update({"n_committed": 0, "kind": spec.kind})
        self._streams[name] = {
            "spec": spec, "group": g, "arrays": arrays, "block": block,
            "buffer": [], "n": 0, "capacity": 0, "last_t": -np.inf,
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
            raise InputError("unknown stream (declare it with add_stream first)", field=stream,
                             expected=f"one of {sorted(self._streams)}")
        spec: StreamSpec = st["spec"]
        t = float(t)
        if not np.isfinite(t):
            raise InputError("timestamp is not finite", field=f"{stream}/t", got=t)
        if t <= st["last_t"]:
            raise InputError("timestamps must be strictly increasing", field=f"{stream}/t",
                             expected=f"> {st['last_t']}", got=t)
        missing = set(spec.fields) - set(values)
        extra = set(values) - set(spec.fields)
        if missing or extra:
            raise InputError("fields do not match the stream declaration", field=stream,
                             expected=f"fields {sorted(spec.fields)}",
                             got=f"missing {sorted(missing)}, unknown {sorted(extra)}")
        row = {"t": t}
        for k, v in values.items():
            fs = spec.fields[k]
            a = np.asarray(v)
            if a.shape != tuple(fs.shape):
                raise InputError("wrong shape", field=f"{stream}/{k}", expected=str(tuple(fs.shape)), got=a.shape)
            if np.dtype(fs.dtype).kind in "ui" and a.dtype.kind == "f":
                raise InputError("float data for an integer field (convert explicitly)",
                                 field=f"{stream}/{k}", expected=fs.dtype, got=str(a.dtype))
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
        _atomic_write_text(self.path / MANIFEST, json.dumps(self.manifest, indent=1, default=_json_default))


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON-serialisable: {type(o).__name__}")


def _vtrack_version() -> str:
    from vtrack import __version__

    return __version__


class FieldReader:
    """Lazy view of one field, limited to the committed frames (indexing reads from disk)."""

    def __init__(self, array: Any, n: int, name: str) -> None:
        self._a = array
        self.n = n
        self.name = name

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.n, *self._a.shape[1:])

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(self._a.dtype)

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, idx: Any) -> np.ndarray:
        if isinstance(idx, (int, np.integer)):
            i = int(idx) + (self.n if idx < 0 else 0)
            if not 0 <= i < self.n:
                raise IndexError(f"{self.name}: frame {idx} out of range (0..{self.n - 1})")
            return np.asarray(self._a[i])
        if isinstance(idx, slice):
            return np.asarray(self._a[slice(*idx.indices(self.n))])
        ids = np.asarray(idx)
        if ids.dtype == bool:
            ids = np.nonzero(ids)[0]
        if ids.size and (ids.min() < -self.n or ids.max() >= self.n):
            raise IndexError(f"{self.name}: frame index out of range (0..{self.n - 1})")
        ids = np.where(ids < 0, ids + self.n, ids)
        return np.asarray(self._a.get_orthogonal_selection((ids,)))

    def all(self) -> np.ndarray:
        return self[:]


class StreamReader:
    """Committed frames of one stream with time-synchronised access."""

    def __init__(self, name: str, group: Any, meta: dict, n: int) -> None:
        self.name = name
        self.meta = meta
        self.kind: str = meta.get("kind", "")
        self.frame: str = meta.get("frame", "")
        self.rate_hz = meta.get("rate_hz")
        self.attrs: dict = meta.get("attrs", {})
        self.n = n
        self._group = group
        self.t = np.asarray(group["t"][:n], dtype=np.float64)
        self.fields = {k: FieldReader(group[k], n, f"{name}/{k}") for k in meta["fields"]}

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, field: str) -> FieldReader:
        try:
            return self.fields[field]
        except KeyError:
            raise InputError("no such field", field=f"{self.name}/{field}",
                             expected=f"one of {sorted(self.fields)}") from None

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

    def sample(self, field: str, times: float | Sequence[float] | np.ndarray,
               mode: Literal["nearest", "linear"] = "nearest") -> np.ndarray:
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

    def __init__(self, path: str | Path) -> None:
        import zarr

        self.path = Path(path)
        mpath = self.path / MANIFEST
        if not self.path.is_dir():
            raise InputError("session directory does not exist", path=self.path)
        if not mpath.exists():
            raise InputError("not a vtrack session (no manifest.json)", path=self.path)
        try:
            self.manifest = json.loads(mpath.read_text())
        except json.JSONDecodeError as e:
            raise InputError(f"corrupt manifest (JSON error at line {e.lineno}: {e.msg})", path=mpath) from None
        if self.manifest.get("format") != FORMAT_NAME:
            raise InputError("not a vtrack session manifest", path=mpath, field="format",
                             expected=FORMAT_NAME, got=self.manifest.get("format"))
        version = self.manifest.get("version")
        if not isinstance(version, int) or version > FORMAT_VERSION:
            raise InputError("unsupported session format version", path=mpath, field="version",
                             expected=f"<= {FORMAT_VERSION}", got=version)
        streams = self.manifest.get("streams")
        if not isinstance(streams, dict):
            raise InputError("manifest has no stream table", path=mpath, field="streams", expected="a mapping")
        self.complete = bool(self.manifest.get("complete"))
        try:
            self._root = zarr.open_group(str(self.path / DATA), mode="r", zarr_format=3)
        except Exception as e:  # zarr raises several types for missing/corrupt stores
            raise InputError(f"cannot open the array store ({type(e).__name__}: {e})",
                             path=self.path / DATA) from None
        self.streams: dict[str, StreamReader] = {}
        for name, meta in streams.items():
            self.streams[name] = self._open_stream(name, meta)

    def _open_stream(self, name: str, meta: dict) -> StreamReader:
        where = self.path / DATA / name
        try:
            g = self._root[name]
            n = int(g.attrs.get("n_committed", -1))
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
                raise InputError("array is shorter than the committed frame count", path=where / fname,
                                 expected=f">= {n} frames", got=arr.shape[0])
            decl = meta["fields"].get(fname) if fname != "t" else None
            if decl is not None and list(arr.shape[1:]) != list(decl["shape"]):
                raise InputError("array shape differs from the manifest", path=where / fname,
                                 expected=str(decl["shape"]), got=list(arr.shape[1:]))
        sr = StreamReader(name, g, meta, n)
        if n > 1:
            bad = np.nonzero(np.diff(sr.t) <= 0)[0]
            if bad.size:
                raise InputError(f"timestamps not strictly increasing at frame {int(bad[0]) + 1}",
                                 path=where / "t")
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
            raise InputError("no such stream in the session", path=self.path, field=name,
                             expected=f"one of {sorted(self.streams)}") from None

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
        return scene_from_dict(self.scene_dict, base_dir=self.path, source=self.path / MANIFEST,
                               check_files=check_files)

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
                "kind": s.kind, "frames": s.n, "t0": float(s.t[0]) if s.n else None,
                "duration_s": span, "rate_hz_measured": (s.n - 1) / span if span > 0 else None,
                "fields": {f: list(fr.shape[1:]) for f, fr in s.fields.items()},
            }
        return out


def open_session(path: str | Path) -> SessionReader:
    """Open and validate a session directory."""
    return SessionReader(path)


def copy_streams(reader: SessionReader, writer: SessionWriter, names: Iterable[str] | None = None) -> None:
    """Copy whole streams from one session into another (used by converters and tests)."""
    for name in names or reader.streams:
        s = reader[name]
        meta = s.meta
        spec = StreamSpec(
            kind=meta["kind"], frame=meta.get("frame", ""), rate_hz=meta.get("rate_hz"), attrs=meta.get("attrs", {}),
            fields={k: FieldSpec(tuple(v["shape"]), v["dtype"], v.get("units", ""), v.get("chunk_frames"))
                    for k, v in meta["fields"].items()},
        )
        writer.add_stream(name, spec)
        for i in range(s.n):
            fr = s.frame_at(i)
            t = fr.pop("t")
            writer.append(name, t, **fr)
