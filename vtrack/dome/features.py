"""Image -> network inputs: marker-graph tensors (GNN) and normalised image pairs (CNN), plus caching.

The GNN node input is the S5 descriptor plus the displacement (units of half the image size) from the
nearest marker of the sensor's reference (no-contact) frame; marker positions are back-projected onto the
rest dome (unit directions) so the decoder can carry their features to the template.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from vtrack.dome.markers import EDGE_DIM, build_graph, extract_markers
from vtrack.dome.model import DomeGeometry, knn_np


def graph_arrays(image: np.ndarray, ref_centers: np.ndarray, geo: DomeGeometry) -> dict[str, np.ndarray]:
    """Marker graph of one image as arrays: x (n, 10), edge_index (2, m), edge_attr (m, 5), pos (n, 3)."""
    ms = extract_markers(image)
    g = build_graph(ms)
    n = len(ms)
    half = geo.cfg.image_size / 2.0
    if n and len(ref_centers):
        idx, _ = knn_np(ms.centers, ref_centers, 1)
        dref = (ms.centers - ref_centers[idx[:, 0]]) / half
    else:
        dref = np.zeros((n, 2))
    x = np.concatenate([g.x, dref.astype(np.float32)], 1) if n else np.zeros((0, 10), np.float32)
    pos = geo.backproject_to_dome(ms.centers) if n else np.zeros((0, 3))
    pos = pos / np.maximum(np.linalg.norm(pos, axis=1, keepdims=True), 1e-9)
    return {"x": x.astype(np.float32), "edge_index": g.edge_index, "edge_attr": g.edge_attr,
            "pos": pos.astype(np.float32), "method": g.method}


def reference_centers(ref_image: np.ndarray) -> np.ndarray:
    return extract_markers(ref_image).centers


def prepare_graphs(data: dict, geo: DomeGeometry, cache_key: str | None = None) -> dict[str, np.ndarray]:
    """Ragged marker graphs of every image in ``data`` (cached next to the dataset when ``cache_key``)."""
    from vtrack.paths import cache_dir

    path: Path | None = None
    if cache_key:
        h = hashlib.sha1(cache_key.encode()).hexdigest()[:12]
        path = cache_dir() / "dome" / f"graphs_{h}.npz"
        if path.exists():
            with np.load(path) as z:
                return {k: z[k] for k in z.files}
    ref = reference_centers(data["reference_image"])
    xs, eis, eas, ps, no, eo = [], [], [], [], [0], [0]
    for img in data["image"]:
        a = graph_arrays(img, ref, geo)
        xs.append(a["x"])
        eis.append(a["edge_index"])
        eas.append(a["edge_attr"])
        ps.append(a["pos"])
        no.append(no[-1] + len(a["x"]))
        eo.append(eo[-1] + a["edge_index"].shape[1])
    out = {"x": np.concatenate(xs), "edge_index": np.concatenate(eis, 1) if eis else np.zeros((2, 0), np.int64),
           "edge_attr": np.concatenate(eas) if eas else np.zeros((0, EDGE_DIM), np.float32),
           "pos": np.concatenate(ps), "node_off": np.array(no), "edge_off": np.array(eo)}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, **out)
        tmp.replace(path)
    return out


def collate_graphs(graphs: list[dict[str, np.ndarray]]) -> dict:
    """Batch single-graph arrays into torch tensors (node offsets added to edge indices)."""
    import torch

    xs, eis, eas, ps, bs = [], [], [], [], []
    off = 0
    for b, g in enumerate(graphs):
        n = len(g["x"])
        xs.append(g["x"])
        eis.append(g["edge_index"] + off)
        eas.append(g["edge_attr"])
        ps.append(g["pos"])
        bs.append(np.full(n, b, np.int64))
        off += n
    return {"x": torch.from_numpy(np.concatenate(xs)), "edge_index": torch.from_numpy(np.concatenate(eis, 1)),
            "edge_attr": torch.from_numpy(np.concatenate(eas)), "pos": torch.from_numpy(np.concatenate(ps)),
            "batch": torch.from_numpy(np.concatenate(bs)), "n_graphs": len(graphs)}


def slice_graph(G: dict[str, np.ndarray], i: int) -> dict[str, np.ndarray]:
    a, b = G["node_off"][i], G["node_off"][i + 1]
    c, d = G["edge_off"][i], G["edge_off"][i + 1]
    return {"x": G["x"][a:b], "edge_index": G["edge_index"][:, c:d], "edge_attr": G["edge_attr"][c:d],
            "pos": G["pos"][a:b]}


def image_batch(images: np.ndarray, ref_image: np.ndarray) -> dict:
    """CNN input: (B, 2, S, S) float tensor [image, reference] scaled to [0, 1]."""
    import torch

    imgs = np.asarray(images, np.float32) / 255.0
    if imgs.ndim == 2:
        imgs = imgs[None]
    ref = np.broadcast_to(np.asarray(ref_image, np.float32) / 255.0, imgs.shape)
    return {"image": torch.from_numpy(np.ascontiguousarray(np.stack([imgs, ref], 1)))}
