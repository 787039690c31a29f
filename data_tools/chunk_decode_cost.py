"""CPU per chunk of ``vtrack.io.chunks.ChunkFiles.read``: decompressed straight into the output array (the zstd
header's size checked) against into a new buffer and copied (the path taken when a header leaves the size out),
alternated pass by pass over every chunk of a session's DIGIT image, camera RGB and depth arrays.

Usage: ``python data_tools/chunk_decode_cost.py [OBJECT [SECONDS [ROUNDS]]]`` (default 006_mustard_bottle, 5 s, none
occlusion, 4 rounds; the first round is a warm-up and not counted). Prints ms of process CPU per chunk.
"""

import sys
import time

import numpy as np


def main(obj: str, seconds: float, rounds: int) -> None:
    from vtrack.threads import limit_threads

    limit_threads(1)
    import vtrack.io.chunks as chunks
    from vtrack.io.session import open_session
    from vtrack.testing.sim import ycb_session

    r = open_session(ycb_session(obj, "none", seconds))
    tactile = sorted(n for n in r.streams if n.startswith("tactile/"))[0]
    fields = [(tactile, "image"), ("camera/cam0", "rgb"), ("camera/cam0", "depth")]
    real = chunks.frame_content_size
    res: dict[str, dict[str, list[float]]] = {"in place": {}, "copied": {}}
    for k in range(rounds):
        for mode in ("in place", "copied") if k % 2 == 0 else ("copied", "in place"):
            chunks.frame_content_size = real if mode == "in place" else (lambda data: None)
            for stream, f in fields:
                cf = r[stream][f]._files
                c, n = cf.chunk_shape[0], len(r[stream][f])
                starts = range(0, n - n % c, c)
                t0 = time.process_time()
                for c0 in starts:
                    cf.read(c0, c0 + c)
                if k:
                    res[mode].setdefault(f"{stream}/{f}", []).append((time.process_time() - t0) * 1e3 / len(starts))
    chunks.frame_content_size = real
    for mode, per in res.items():
        print(mode, {name: round(float(np.mean(v)), 3) for name, v in per.items()})


if __name__ == "__main__":
    a = sys.argv[1:]
    main(a[0] if a else "006_mustard_bottle", float(a[1]) if len(a) > 1 else 5.0, int(a[2]) if len(a) > 2 else 4)
