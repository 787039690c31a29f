"""Reading a session array's chunk files directly, without Zarr's asynchronous machinery.

A session's arrays are Zarr v3 arrays that :class:`vtrack.io.session.SessionWriter` writes with one layout: chunks
along the frame axis only, codecs ``bytes -> zstd -> crc32c``, the default chunk-key encoding, on a local disk.
Reading such a chunk through Zarr costs about twice the decompression itself (its event loop, thread hand-offs and
buffer copies): 13.6 against 7.8 ms of CPU per camera frame for one camera's RGB-D and four DIGITs, mean of 3
alternated rounds on the 5 s mustard session (``data_tools/read_cost.py``). For that layout :class:`ChunkFiles`
reads the chunk file, checks its CRC32C and decompresses it with the same libraries Zarr uses (numcodecs' Zstd,
google-crc32c), and Zarr's own metadata gives the file names. A chunk whose zstd header declares its full size
is decompressed straight into the output array (:func:`frame_content_size`; zstd then checks the data against that
size): no intermediate buffer and no copy. Any other array (another codec, sharding, a remote
store, a chunk file that is missing) is read through Zarr as before: :meth:`ChunkFiles.of` returns None, or
:meth:`ChunkFiles.read` returns None for the block. ``tests/io/test_chunks.py`` checks the two agree bit for bit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


class ChunkFiles:
    """Frames ``c0..c1-1`` of one array decoded straight from its chunk files (see the module docstring).

    Args:
        root: the array's folder (its ``zarr.json``'s folder).
        chunk_shape: the regular chunk shape; ``chunk_shape[1:]`` is the array's frame shape.
        dtype: element type, as stored (byte order included).
        encode_key: Zarr's chunk-key encoder (chunk index tuple -> relative file name).
    """

    def __init__(self, root: Path, chunk_shape: tuple[int, ...], dtype: np.dtype, encode_key: Any) -> None:
        from numcodecs import Zstd

        self.root = Path(root)
        self.chunk_shape = tuple(int(c) for c in chunk_shape)
        self.dtype = np.dtype(dtype)
        self._key = encode_key
        self._zstd = Zstd()
        self.chunk_bytes = int(np.prod(self.chunk_shape, dtype=np.int64)) * self.dtype.itemsize

    @classmethod
    def of(cls, array: Any) -> ChunkFiles | None:
        """A reader for ``array`` (a ``zarr.Array``) if it has vtrack's layout on a local disk, else None."""
        try:
            from zarr.codecs import BytesCodec, Crc32cCodec, ZstdCodec
            from zarr.core.chunk_grids import RegularChunkGrid
            from zarr.storage import LocalStore

            md = array.metadata
            codecs = tuple(md.codecs)
            if not isinstance(array.store, LocalStore) or getattr(md, "zarr_format", 3) != 3:
                return None
            if [type(c) for c in codecs] != [BytesCodec, ZstdCodec, Crc32cCodec]:
                return None
            if md.storage_transformers or not isinstance(md.chunk_grid, RegularChunkGrid):
                return None
            chunks = tuple(int(c) for c in md.chunk_grid.chunk_shape)
            shape = tuple(int(s) for s in array.shape)
            dtype = np.dtype(array.dtype)
            if not shape or chunks[1:] != shape[1:] or dtype.kind not in "biuf":
                return None
            if dtype.itemsize > 1:
                endian = getattr(codecs[0].endian, "value", codecs[0].endian)
                if endian not in ("little", "big"):
                    return None
                dtype = dtype.newbyteorder("<" if endian == "little" else ">")
            root = Path(array.store.root) / array.path
            if not (root / "zarr.json").is_file():
                return None
            return cls(root, chunks, dtype, md.chunk_key_encoding.encode_chunk_key)
        except Exception:  # noqa: BLE001 - any doubt about the layout: Zarr reads it
            return None

    def read(self, c0: int, c1: int) -> np.ndarray | None:
        """Frames ``c0..c1-1`` (``c0`` on a chunk boundary) as one array in native byte order; None when a chunk
        file is missing (Zarr then decides: fill value or damage). A checksum mismatch, a short file or a chunk
        that does not decompress to its size raises ValueError (the caller reports the frames as corrupt)."""
        import google_crc32c

        c = self.chunk_shape[0]
        if c0 % c or c1 <= c0:
            raise ValueError(f"block {c0}..{c1 - 1} does not start on a chunk boundary of {c} frames")
        k0, k1 = c0 // c, -(-c1 // c)
        out = np.empty(((k1 - k0) * c, *self.chunk_shape[1:]), self.dtype)
        flat = out.reshape(k1 - k0, -1).view(np.uint8)
        tail = (0,) * (len(self.chunk_shape) - 1)
        for k in range(k0, k1):
            try:
                data = (self.root / self._key((k, *tail))).read_bytes()
            except FileNotFoundError:
                return None
            if len(data) < 5:
                raise ValueError(f"chunk {k}: {len(data)} bytes")
            body = np.frombuffer(data, np.uint8)[:-4]  # a view: no copy of the chunk
            if google_crc32c.value(body) != int.from_bytes(data[-4:], "little"):
                raise ValueError(f"chunk {k}: CRC32C checksum mismatch")
            if frame_content_size(body) == self.chunk_bytes:
                # straight into ``out``: no intermediate buffer (its allocation faults in fresh pages) and no copy:
                # 3.2 -> 1.8 ms CPU per 4-frame DIGIT chunk (data_tools/chunk_decode_cost.py). The header's size is
                # checked here and zstd checks the data against it (a frame that decodes to another size is an
                # error), so a short chunk is caught as before; numcodecs raises for a second frame (its expected
                # size then exceeds the buffer)
                try:
                    self._zstd.decode(body, flat[k - k0])
                except (RuntimeError, ValueError) as e:
                    raise ValueError(f"chunk {k}: {e}") from None
                continue
            raw = self._zstd.decode(body)
            if len(raw) != self.chunk_bytes:
                raise ValueError(f"chunk {k}: decompressed to {len(raw)} bytes, expected {self.chunk_bytes}")
            flat[k - k0] = np.frombuffer(raw, np.uint8)
        block = out[: c1 - c0]
        return block if self.dtype.isnative else block.astype(self.dtype.newbyteorder("="))


#: the zstd frame magic number, little-endian on disk (RFC 8878, 3.1.1)
_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


def frame_content_size(data: np.ndarray | bytes) -> int | None:
    """The content size a zstd frame's header declares (RFC 8878, 3.1.1.1), or None when ``data`` does not start
    with a zstd frame or its header leaves the size out."""
    b = bytes(data[:18])  # magic 4 + descriptor 1 + window 1 + dictionary id <= 4 + content size <= 8
    if len(b) < 5 or b[:4] != _ZSTD_MAGIC:
        return None
    fhd = b[4]
    single = (fhd >> 5) & 1
    fcs_flag = fhd >> 6
    fcs_bytes = (0, 2, 4, 8)[fcs_flag] or (1 if single else 0)
    if not fcs_bytes:
        return None
    pos = 5 + (0 if single else 1) + (0, 1, 2, 4)[fhd & 3]
    if len(b) < pos + fcs_bytes:
        return None
    size = int.from_bytes(b[pos : pos + fcs_bytes], "little")
    return size + 256 if fcs_bytes == 2 else size
