"""Direct chunk-file reads (vtrack.io.chunks): the same arrays as Zarr's, damage reported, anything else left to
Zarr."""

import shutil

import numpy as np
import pytest


def _arrays(root):
    """Every array under a Zarr group, with its path."""
    import zarr

    g = zarr.open_group(str(root), mode="r")
    out = []

    def walk(grp, prefix):
        for name, a in grp.arrays():
            out.append((f"{prefix}{name}", a))
        for name, sub in grp.groups():
            walk(sub, f"{prefix}{name}/")

    walk(g, "")
    return out


def test_every_session_array_reads_the_same_as_through_zarr(tiny_session):
    from vtrack.io.chunks import ChunkFiles

    arrays = _arrays(tiny_session / "data.zarr")
    kinds = set()
    for name, a in arrays:
        cf = ChunkFiles.of(a)
        assert cf is not None, f"{name}: written by vtrack, so its layout is the one read directly"
        n, c = a.shape[0], a.chunks[0]
        if n == 0:
            continue
        got = cf.read(0, n)
        want = a[:]
        assert got.dtype == want.dtype and got.shape == want.shape, name
        assert np.array_equal(got, want, equal_nan=want.dtype.kind == "f"), name
        if n > c:  # a block that starts at a later chunk and ends inside the last one
            assert np.array_equal(cf.read(c, n), want[c:n], equal_nan=want.dtype.kind == "f"), name
        kinds.add(a.dtype.kind)
    assert {"u", "f"} <= kinds  # images and depth (unsigned) and times / joints (float) were among them
    with pytest.raises(ValueError, match="chunk boundary"):
        ChunkFiles.of(dict(arrays)["camera/cam0/t"]).read(1, 3)


def test_a_damaged_chunk_is_reported_a_missing_one_left_to_zarr(tiny_session, tmp_path):
    import zarr
    from numcodecs import Zstd

    from vtrack.io.chunks import ChunkFiles
    from vtrack.io.session import CorruptDataError, open_session

    s = tmp_path / "s"
    shutil.copytree(tiny_session, s)
    arr_dir = s / "data.zarr" / "camera" / "cam0" / "depth"
    a = zarr.open_array(str(arr_dir), mode="r")
    cf = ChunkFiles.of(a)
    frame2 = np.asarray(a[2])
    chunk = arr_dir / "c" / "2" / "0" / "0"
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped byte, the length unchanged
    chunk.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="CRC32C"):
        cf.read(2, 3)
    # through the session reader: one line naming the field and the frame
    r = open_session(s)
    with pytest.raises(CorruptDataError, match=r"camera/cam0/depth.*frame 2"):
        r["camera/cam0"]["depth"][2]
    assert np.array_equal(r["camera/cam0"]["depth"][1], a[1])  # the frames beside it still read
    # a chunk whose checksum is right but that decompresses to too few bytes (a writer's bug, not bit rot)
    import google_crc32c

    body = Zstd(3).encode(np.zeros(10, np.uint8).tobytes())
    chunk.write_bytes(body + np.uint32(google_crc32c.value(body)).tobytes())
    with pytest.raises(ValueError, match="decompressed to 10 bytes"):
        cf.read(2, 3)
    # the header declares the chunk's full size (the path that decodes into the output directly), but the data
    # ends early, or a second frame follows: damage too, never a half-filled frame
    full = Zstd(3).encode(frame2.tobytes())
    for bad in (full[: len(full) * 3 // 4], full + Zstd(3).encode(b"x" * 10)):
        chunk.write_bytes(bad + np.uint32(google_crc32c.value(bad)).tobytes())
        with pytest.raises(ValueError, match="chunk 2"):
            cf.read(2, 3)
    chunk.write_bytes(full + np.uint32(google_crc32c.value(full)).tobytes())
    assert np.array_equal(cf.read(2, 3)[0], frame2)
    chunk.unlink()  # missing: not this reader's call (Zarr gives the fill value or its own error)
    assert cf.read(2, 3) is None and cf.read(0, 2) is not None


def test_other_layouts_are_read_through_zarr(tmp_path):
    import zarr

    from vtrack.io.chunks import ChunkFiles
    from vtrack.io.session import FieldReader

    x = (np.arange(6 * 5 * 3, dtype=np.uint16).reshape(6, 5, 3) * 37) % 1000
    # big-endian bytes: read directly, returned in native byte order
    big = zarr.create_array(
        str(tmp_path / "big"), shape=x.shape, chunks=(2, 5, 3), dtype="uint16",
        serializer=zarr.codecs.BytesCodec(endian="big"),
        compressors=[zarr.codecs.ZstdCodec(level=3), zarr.codecs.Crc32cCodec()],
    )  # fmt: skip
    big[:] = x
    cf = ChunkFiles.of(big)
    assert cf is not None
    got = cf.read(2, 6)
    assert got.dtype.isnative and np.array_equal(got, x[2:])
    # no checksum codec, another compressor, chunks that split a frame, an in-memory store: Zarr reads those
    plain = zarr.create_array(str(tmp_path / "plain"), shape=x.shape, chunks=(2, 5, 3), dtype="uint16")
    split = zarr.create_array(
        str(tmp_path / "split"), shape=x.shape, chunks=(2, 5, 1), dtype="uint16",
        compressors=[zarr.codecs.ZstdCodec(level=3), zarr.codecs.Crc32cCodec()],
    )  # fmt: skip
    mem = zarr.create_array(zarr.storage.MemoryStore(), shape=x.shape, chunks=(2, 5, 3), dtype="uint16")
    for a in (plain, split, mem):
        a[:] = x
        assert ChunkFiles.of(a) is None
        fr = FieldReader(a, 6, "test/x")
        assert np.array_equal(np.stack([fr[i] for i in range(6)]), x)
    fr = FieldReader(big, 6, "test/big")
    assert fr._files is not None and np.array_equal(np.stack([fr[i] for i in range(6)]), x)
    # slices (the live replay's block reads) from any frame, not only a chunk's first
    for sl in (slice(1, 5), slice(2, 6), slice(3, 4), slice(0, 6, 2), slice(5, 2)):
        assert np.array_equal(fr[sl], x[sl]), sl


def test_zstd_frame_content_size_is_read_from_the_header():
    from numcodecs import Zstd

    from vtrack.io.chunks import frame_content_size

    rng = np.random.default_rng(0)
    # 1-, 2- (+256), 4- and 8-byte size fields; levels that write the header differently
    for n in (0, 7, 255, 256, 300, 65791, 70000, 1 << 20):
        for level in (1, 3, 19):
            data = rng.integers(0, 4, n).astype(np.uint8)
            assert frame_content_size(np.frombuffer(Zstd(level).encode(data), np.uint8)) == n, (n, level)
    assert frame_content_size(b"not a zstd frame") is None and frame_content_size(b"\x28\xb5") is None
    # a streamed frame may leave the size out (descriptor 0x00: no size field, not single-segment)
    assert frame_content_size(b"\x28\xb5\x2f\xfd\x00\x58\x00\x00") is None
