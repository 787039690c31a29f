"""Image -> network inputs: marker-graph tensors (GNN) and normalised image pairs (CNN), plus caching.

The GNN node input is the S5 descriptor plus reference-relative features from the one-to-one match of
each marker to the sensor's reference (no-contact) frame: displacement (units of the rest-marker spacing),
area and radius change, matched flag; marker positions are back-projected onto the
rest dome (unit directions) so the decoder can carry their features to the template.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from vtrack.dome.markers import EDGE_DIM, NODE_DIM, MarkerSet, build_graph, extract_markers
from vtrack.dome.model import DomeGeometry

FEATURE_VERSION = 3  # bump when the node features change: it salts the graph cache key
REL_DIM = 5  # reference-relative node features appended to the S5 descriptor
EDGE_REL_DIM = 3  # reference-relative edge features (strain) appended to the S5 edge attributes


def gated_assignment(a: np.ndarray, b: np.ndarray, tree_b, gate: float) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matching of points ``a`` (n, 2) to ``b`` (m, 2) that first maximises the number of pairs
    closer than ``gate`` and then minimises their total distance (the Hungarian problem with gated costs).

    Why not one dense ``linear_sum_assignment``: for 331 markers it cost ~6 ms a frame, a third of the
    frame budget. The gated problem splits into the connected components of the bipartite graph of pairs
    within the gate; almost all components are a single pair (motion < gate), and only the few ambiguous
    ones need the Hungarian solver. Same optimum as the dense solver (up to ties).
    """
    from scipy.optimize import linear_sum_assignment
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n, m = len(a), len(b)
    if n == 0 or m == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if not np.isfinite(gate):
        d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
        return linear_sum_assignment(d)
    # all pairs within the gate, vectorised: k nearest with an upper bound, k doubled until no row is full
    k = min(4, m)
    while True:
        dk, jk = tree_b.query(a, k=k, distance_upper_bound=gate)
        dk, jk = dk.reshape(n, k), jk.reshape(n, k)
        if k >= m or not np.isfinite(dk[:, -1]).any():
            break
        k = min(2 * k, m)
    within = np.isfinite(dk)
    if not within.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ii = np.nonzero(within)[0].astype(np.int64)
    jj = jk[within].astype(np.int64)
    dist = dk[within]
    # a pair whose two ends have no other candidate is its own component: no solver needed
    single = (np.bincount(ii, minlength=n)[ii] == 1) & (np.bincount(jj, minlength=m)[jj] == 1)
    rows, cols = [ii[single]], [jj[single]]
    if single.all():
        return np.concatenate(rows), np.concatenate(cols)
    # bipartite graph of the remaining pairs: nodes 0..n-1 detections, n..n+m-1 reference markers
    ii_, jj_ = ii[~single], jj[~single]
    g = coo_matrix((np.ones(len(ii_)), (ii_, n + jj_)), shape=(n + m, n + m))
    _, comp = connected_components(g, directed=False)
    ec = np.full(len(ii), -1, np.int64)
    ec[~single] = comp[ii_]  # component of each ambiguous candidate pair
    big = 1e6
    for c in np.unique(ec[~single]):
        sel = ec == c
        ri, ci = np.unique(ii[sel], return_inverse=True)
        rj, cj = np.unique(jj[sel], return_inverse=True)
        cost = np.full((len(ri), len(rj)), big)
        cost[ci, cj] = dist[sel]
        r, k = linear_sum_assignment(cost)
        ok = cost[r, k] < big
        rows.append(ri[r[ok]])
        cols.append(rj[k[ok]])
    return np.concatenate(rows), np.concatenate(cols)


def reference_index(ref: MarkerSet, half: float) -> tuple:
    """(KD-tree of the reference centres, median rest-marker spacing px, matching gate px) of a reference
    marker set; ``half`` (px, half the image size) stands in for the spacing of a one-marker reference.

    The reference is fixed for a session, so this is built once and cached on the set (keyed on its centres
    array): every frame's matching and validity check read it."""
    from scipy.spatial import cKDTree

    cached = getattr(ref, "_index", None)
    if cached is not None and cached[0] is ref.centers and cached[1] == half:
        return cached[2:]
    tree = cKDTree(ref.centers)
    if len(ref) >= 2:
        nn_d, _ = tree.query(ref.centers, k=2)
        spacing = max(float(np.median(nn_d[:, 1])), 1e-6)
        gate = 0.75 * spacing
    else:
        spacing, gate = half, np.inf
    ref._index = (ref.centers, half, tree, spacing, gate)
    return tree, spacing, gate


def _match(ms: MarkerSet, ref: MarkerSet, half: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Partner rest marker of each detected marker (nearest when unmatched), matched flags, and the
    median rest-marker spacing (px) used as the unit of the relative features. Needs ``len(ref) >= 1``."""
    n = len(ms)
    tree, spacing, gate = reference_index(ref, half)
    partner = tree.query(ms.centers, k=1)[1].astype(np.int64).reshape(n)
    rows, cols = gated_assignment(ms.centers, ref.centers, tree, gate)
    matched = np.zeros(n, bool)
    partner[rows] = cols
    matched[rows] = True
    return partner, matched, spacing


def edge_strain(
    ms: MarkerSet, ref: MarkerSet, edge_index: np.ndarray, half: float, match: tuple | None = None
) -> np.ndarray:
    """Reference-relative edge features (m, 3) float32: ``[d_dx, d_dy, d_len]``, the change of the edge
    vector (and of its length) between the two markers from the reference frame to this frame, in units of
    the median rest-marker spacing; 0 for edges with an unmatched end.

    Why: a press shows up as local stretching/compression of the marker net around the contact, a
    differential signal that node displacements only carry implicitly and that is blind to common-mode
    motion (inflation, whole-dome shifts).
    """
    e = np.asarray(edge_index, np.int64).reshape(2, -1)
    out = np.zeros((e.shape[1], EDGE_REL_DIM), np.float32)
    if e.shape[1] == 0 or len(ms) == 0 or len(ref) == 0:
        return out
    partner, matched, spacing = match or _match(ms, ref, half)
    ok = matched[e[0]] & matched[e[1]] & (partner[e[0]] != partner[e[1]])
    v = ms.centers[e[1]] - ms.centers[e[0]]
    v0 = ref.centers[partner[e[1]]] - ref.centers[partner[e[0]]]
    d = (v - v0) / spacing
    dl = (np.linalg.norm(v, axis=1) - np.linalg.norm(v0, axis=1)) / spacing
    out[ok, :2] = d[ok]
    out[ok, 2] = dl[ok]
    return np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)


def match_reference(ms: MarkerSet, ref: MarkerSet, half: float, match: tuple | None = None) -> np.ndarray:
    """Reference-relative node features (n, 5) float32: ``[dx, dy, d_area, d_r, matched]``.

        Each detected marker is matched one-to-one to a rest marker of the no-contact reference frame
        (Hungarian assignment on pixel distance, ``scipy.optimize.linear_sum_assignment``), gated at 0.75
        of the median rest-marker spacing so a vanished/merged marker does not steal a far partner. ``dx, dy``
        is the image displacement from the partner in units of the median rest-marker spacing (a fixed
    normalisation of the image coordinates, ~8 px at 160 px for the simulated dome); unmatched markers take
        their nearest rest marker for ``dx, dy`` and get ``matched = 0``. ``d_area`` is the area change in
        units of the median rest area; ``d_r`` the change of equivalent radius sqrt(area/pi) in units of the
        median rest radius (both 0 when unmatched, or when the reference has no areas).
    """
    n, m = len(ms), len(ref)
    out = np.zeros((n, REL_DIM), np.float32)
    if n == 0 or m == 0:
        return out
    partner, matched, spacing = match or _match(ms, ref, half)
    # in rest-marker spacings, not half-image units: displacements are 1-3 px, i.e. ~0.01-0.04 of half
    # the image, too small next to the O(1) S5 fields for the input MLP to pick up within the budget
    out[:, :2] = (ms.centers - ref.centers[partner]) / spacing
    ra = np.asarray(ref.areas, np.float64)
    if len(ra) == m and np.all(np.isfinite(ra)) and float(np.median(ra)) > 0:
        med = float(np.median(ra))
        da = (ms.areas - ra[partner]) / med
        dr = (np.sqrt(ms.areas) - np.sqrt(ra[partner])) / np.sqrt(med)
        out[:, 2] = np.where(matched, da, 0.0)
        out[:, 3] = np.where(matched, dr, 0.0)
    out[:, 4] = matched
    return np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)


def _as_reference(ref: MarkerSet | np.ndarray) -> MarkerSet:
    """Accept a reference MarkerSet, or bare rest centres (n, 2) px (then area changes are 0)."""
    if isinstance(ref, MarkerSet):
        return ref
    c = np.asarray(ref, np.float64).reshape(-1, 2)
    return MarkerSet(c, np.full(len(c), np.nan), np.zeros((len(c), 2)), np.zeros(len(c)), (0, 0))


def graph_arrays(
    image: np.ndarray, ref: MarkerSet | np.ndarray, geo: DomeGeometry, markers: MarkerSet | None = None
) -> dict[str, np.ndarray]:
    """Marker graph of one image as arrays: x (n, 13), edge_index (2, m), edge_attr (m, 8) (S5 edge attributes +
    :func:`edge_strain`), pos (n, 3).

    ``ref`` is the reference (no-contact) frame's markers (``reference_markers``) or its bare centres; the
    reference is captured at the frame's operating pressure when ``geo.cfg.reference_at_pressure``.
    ``markers``: the image's markers when the caller already extracted them.
    """
    ms = markers if markers is not None else extract_markers(image)
    g = build_graph(ms)
    n = len(ms)
    half = geo.cfg.image_size / 2.0
    ref = _as_reference(ref)
    match = _match(ms, ref, half) if n and len(ref) else None
    rel = match_reference(ms, ref, half, match)
    x = np.concatenate([g.x, rel], 1) if n else np.zeros((0, NODE_DIM + REL_DIM), np.float32)
    ea = np.concatenate([g.edge_attr, edge_strain(ms, ref, g.edge_index, half, match)], 1).astype(np.float32)
    pos = geo.backproject_to_dome(ms.centers) if n else np.zeros((0, 3))
    pos = pos / np.maximum(np.linalg.norm(pos, axis=1, keepdims=True), 1e-9)
    return {
        "x": x.astype(np.float32),
        "edge_index": g.edge_index,
        "edge_attr": ea,
        "pos": pos.astype(np.float32),
        "method": g.method,
    }


def reference_centers(ref_image: np.ndarray) -> np.ndarray:
    return extract_markers(ref_image).centers


def reference_markers(ref_image: np.ndarray) -> MarkerSet:
    """Markers of the sensor's no-contact reference frame (rest positions and sizes)."""
    return extract_markers(ref_image)


def prepare_graphs(data: dict, geo: DomeGeometry, cache_key: str | None = None) -> dict[str, np.ndarray]:
    """Ragged marker graphs of every image in ``data`` (cached next to the dataset when ``cache_key``)."""
    from vtrack.paths import cache_dir

    path: Path | None = None
    if cache_key:
        h = hashlib.sha1(f"{cache_key}-f{FEATURE_VERSION}".encode()).hexdigest()[:12]
        path = cache_dir() / "dome" / f"graphs_{h}.npz"
        if path.exists():
            with np.load(path) as z:
                return {k: z[k] for k in z.files}
    refs = np.asarray(data["reference_image"])
    shared = reference_markers(refs) if refs.ndim == 2 else None  # else one reference frame per sample
    xs, eis, eas, ps, no, eo = [], [], [], [], [0], [0]
    for i, img in enumerate(data["image"]):
        a = graph_arrays(img, shared if shared is not None else reference_markers(refs[i]), geo)
        xs.append(a["x"])
        eis.append(a["edge_index"])
        eas.append(a["edge_attr"])
        ps.append(a["pos"])
        no.append(no[-1] + len(a["x"]))
        eo.append(eo[-1] + a["edge_index"].shape[1])
    out = {
        "x": np.concatenate(xs),
        "edge_index": np.concatenate(eis, 1) if eis else np.zeros((2, 0), np.int64),
        "edge_attr": np.concatenate(eas) if eas else np.zeros((0, EDGE_DIM + EDGE_REL_DIM), np.float32),
        "pos": np.concatenate(ps),
        "node_off": np.array(no),
        "edge_off": np.array(eo),
    }
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
    return {
        "x": torch.from_numpy(np.concatenate(xs)),
        "edge_index": torch.from_numpy(np.concatenate(eis, 1)),
        "edge_attr": torch.from_numpy(np.concatenate(eas)),
        "pos": torch.from_numpy(np.concatenate(ps)),
        "batch": torch.from_numpy(np.concatenate(bs)),
        "n_graphs": len(graphs),
    }


def slice_graph(G: dict[str, np.ndarray], i: int) -> dict[str, np.ndarray]:
    a, b = G["node_off"][i], G["node_off"][i + 1]
    c, d = G["edge_off"][i], G["edge_off"][i + 1]
    return {
        "x": G["x"][a:b],
        "edge_index": G["edge_index"][:, c:d],
        "edge_attr": G["edge_attr"][c:d],
        "pos": G["pos"][a:b],
    }


def image_batch(images: np.ndarray, ref_image: np.ndarray) -> dict:
    """CNN input: (B, 2, S, S) float tensor [image, reference] scaled to [0, 1]; ``ref_image`` is one
    reference (S, S) for all images or one per image (B, S, S)."""
    import torch

    imgs = np.asarray(images, np.float32) / 255.0
    if imgs.ndim == 2:
        imgs = imgs[None]
    ref = np.broadcast_to(np.asarray(ref_image, np.float32).reshape((-1,) + imgs.shape[1:]) / 255.0, imgs.shape)
    return {"image": torch.from_numpy(np.ascontiguousarray(np.stack([imgs, ref], 1)))}
