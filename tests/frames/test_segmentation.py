"""HandAwareSegmenter on the cached tiny session (GT read here for scoring only)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from vtrack.errors import InputError

STRIDE = 4


@pytest.fixture(scope="module")
def frames(tiny_session):
    """Segmenter factory + (depth m, q, GT mask) of 8 frames at stride 4 of the tiny session."""
    from vtrack.bench.segmentation import gt_mask_field, segmenter_for_session
    from vtrack.io.session import open_session

    r = open_session(tiny_session)
    s = r["camera/cam0"]
    gts, gtf = gt_mask_field(r, "cam0")
    seg = segmenter_for_session(r, "cam0", STRIDE)
    J = r["joints"]
    out = []
    for i in range(0, len(s), max(1, len(s) // 8)):
        depth = (s["depth"][i][::STRIDE, ::STRIDE] * float(s.attrs["depth_scale"])).astype(np.float32)
        q = seg.kin.reorder(J.sample("q", np.array([s.t[i]]), mode="linear")[0], J.attrs["joint_names"])
        out.append((depth, q, gts[gtf][i][::STRIDE, ::STRIDE].astype(bool)))

    def make(options=None):
        return segmenter_for_session(r, "cam0", STRIDE, options)

    return make, out


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def test_iou_and_hand_removed(frames):
    make, data = frames
    seg = make()
    ious, left = [], []
    for depth, q, gt in data:
        res = seg.segment(depth, q)
        assert res.mask.shape == depth.shape and res.mask.dtype == bool
        assert res.points_world.shape == (int(res.mask[depth > 0].sum()), 3)
        assert np.all(np.isfinite(res.points_world))
        ious.append(_iou(res.mask, gt))
        hand = (depth > 0) & ~gt  # the simulator renders only object + hand
        left.append((res.mask & hand).sum() / hand.sum())
    # Measured 0.912 median (min 0.882) on all 30 frames.
    assert np.median(ious) > 0.85
    assert max(left) < 0.02
    # Without hand removal most hand pixels stay (the check above can fail).
    seg_off = make(_opts(hand_removal=False))
    depth, q, gt = data[0]
    res = seg_off.segment(depth, q)
    assert ((res.mask & (depth > 0) & ~gt).sum() / ((depth > 0) & ~gt).sum()) > 0.3


def _opts(**kw):
    from vtrack.frames.segmentation import SegmentationOptions

    return SegmentationOptions(**kw)


def test_world_points_match_mask_and_centroid_near_sensors(frames):
    make, data = frames
    seg = make()
    depth, q, gt = data[0]
    res = seg.segment(depth, q)
    sensors = np.array([T[0, :3, 3] for T in seg.kin.sensor_poses(q).values()])
    # The held object lies between the fingertips: centroid within a few cm of their mean.
    assert np.linalg.norm(res.points_world.mean(0) - sensors.mean(0)) < 0.05
    assert res.info["hand_removal"] == "done" and res.info["n_hand_removed"] > 100


def _add_plane(seg, depth: np.ndarray, gt: np.ndarray, behind_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Depth with a plane facing the camera ``behind_m`` behind the object's farthest point; its pixels."""
    z_far = float(depth[gt].max()) + behind_m
    cam = seg.cam
    n_c = np.array([0.0, 0.3, -1.0])  # tilted table/wall normal in the camera frame (towards the camera)
    n_c /= np.linalg.norm(n_c)
    p0 = np.array([0.0, 0.0, z_far])
    # Ray (x, y, 1) * t hits the plane at t = n.p0 / n.(x, y, 1).
    den = n_c[0] * seg._rx + n_c[1] * seg._ry + n_c[2]
    t = (n_c @ p0) / den
    plane = (t > 0.05) & (t < 2.0)
    assert cam.width == depth.shape[1]
    out = depth.copy()
    put = plane & ((depth == 0) | (depth > t))
    out[put] = t[put].astype(np.float32)
    return out, put


def test_plane_removed(frames):
    make, data = frames
    depth, q, gt = data[2]
    seg = make()
    d2, plane = _add_plane(seg, depth, gt, behind_m=0.012)
    res = seg.segment(d2, q)
    removed = [p for p in res.info["planes"] if p.get("removed")]
    assert removed, res.info["planes"]
    assert (res.mask & plane).sum() / plane.sum() < 0.01
    assert _iou(res.mask, gt) > 0.8
    # Without plane removal the plane (1.2 cm behind, within the merge gap) joins the object.
    res_off = make(_opts(plane_removal=False)).segment(d2, q)
    assert (res_off.mask & plane).sum() > 5 * max((res.mask & plane).sum(), 1)


def test_hard_cases(frames):
    make, data = frames
    depth, q, gt = data[1]
    seg = make()
    r = seg.segment(np.zeros_like(depth), q)
    assert not r.mask.any() and r.points_world.shape == (0, 3) and "valid depth" in r.info["empty_reason"]
    # The hand hides the whole object: only hand depth left.
    r = seg.segment(np.where(gt, 0, depth).astype(np.float32), q)
    assert not r.mask.any() and "empty_reason" in r.info
    # NaN q: no hand removal (said so), still a mask without exceptions.
    r = seg.segment(depth, np.full_like(q, np.nan))
    assert "NaN" in r.info["hand_removal"] and r.mask.any()
    # No hand model at all; NaN depth pixels are invalid, not points.
    from vtrack.frames.segmentation import HandAwareSegmenter

    d_nan = depth.copy()
    d_nan[:5] = np.nan
    r = HandAwareSegmenter(None, seg.cam, seg.T_world_camera).segment(d_nan, None)
    assert r.info["hand_removal"].startswith("skipped") and np.all(np.isfinite(r.points_world))
    with pytest.raises(InputError, match="depth_m"):
        seg.segment(depth[:-1], q)
    with pytest.raises(InputError, match="'q'"):
        seg.segment(depth, q[:-1])
    with pytest.raises(InputError, match="contacts_world"):
        seg.segment(depth, q, contacts_world=np.zeros((3, 2)))


def test_temporal_state_and_reset(frames):
    make, data = frames
    seg = make()
    depth, q, gt = data[0]
    # A distractor blob (10x10 px) 6 cm in front of the object is not the object.
    r0 = seg.segment(depth, q)
    assert seg._prev_centroid is not None
    d2 = depth.copy()
    rr, cc = np.nonzero(gt)
    r_c, c_c = int(rr.mean()), int(cc.mean())
    d2[r_c - 5 : r_c + 5, c_c + 25 : c_c + 35] = float(depth[gt].min()) - 0.06
    r1 = seg.segment(d2, q)
    assert not r1.mask[r_c - 5 : r_c + 5, c_c + 25 : c_c + 35].any()
    assert _iou(r1.mask, r0.mask) > 0.9
    seg.reset()
    assert seg._prev_centroid is None


def test_any_resolution_and_time(frames):
    make, data = frames
    seg = make()
    times = []
    for depth, q, _ in data:
        c0 = time.process_time()
        seg.segment(depth, q)
        times.append((time.process_time() - c0) * 1e3)
    # Measured ~4 ms CPU at 160x120; loose bound for busy CI machines.
    assert np.median(times[1:]) < 50
    # Half the resolution (stride 8): a strided camera of the strided camera still segments the object.
    from vtrack.frames.segmentation import HandAwareSegmenter
    from vtrack.geometry.camera import PinholeCamera

    c = seg.cam
    cam2 = PinholeCamera(len(range(0, c.width, 2)), len(range(0, c.height, 2)), c.fx / 2, c.fy / 2, c.cx / 2, c.cy / 2)
    seg2 = HandAwareSegmenter(seg.kin, cam2, seg.T_world_camera)
    depth, q, gt = data[3]
    r = seg2.segment(depth[::2, ::2], q)
    assert _iou(r.mask, gt[::2, ::2]) > 0.75


def _full_raycast_hand(seg, q) -> np.ndarray:
    """(H, W) depth of the posed hand by casting every pixel against the world-posed link meshes."""
    from vtrack.geometry.raycast import Raycaster
    from vtrack.kinematics.hand import decimated_link_meshes

    poses = seg.kin.link_poses(q)
    meshes = [
        (v @ poses[k][0][:3, :3].T + poses[k][0][:3, 3], f)
        for k, parts in decimated_link_meshes(seg.kin).items()
        for v, f in parts
    ]
    T = seg.T_world_camera
    d = np.stack([seg._rx, seg._ry, np.ones_like(seg._rx)], -1) @ T[:3, :3].T
    return Raycaster(meshes).cast(np.broadcast_to(T[:3, 3], d.shape), d)["t"]


def test_exact_silhouette_matches_a_full_raycast(frames):
    """The splat's edges re-cast exactly: the hand silhouette equals casting every pixel (the splat alone
    is off along every edge, which cut a quarter off a can seen between two fingers)."""
    make, data = frames
    seg, splat = make(), make(_opts(exact_silhouette=False))
    for _depth, q, _gt in data[:3]:
        ref = np.isfinite(_full_raycast_hand(seg, q))
        exact = np.isfinite(seg.render_hand_depth(seg.kin.link_poses(q), with_core=True)[0])
        rough = np.isfinite(splat.render_hand_depth(splat.kin.link_poses(q), with_core=True)[0])
        assert ref.sum() > 500
        # measured: 0-1 differing pixels (float32 rays on a triangle edge) vs ~100 for the splat
        assert (exact != ref).sum() <= 3
        assert (rough != ref).sum() > 20


def test_refine_skips_nothing_that_matters(frames):
    """The silhouette refinement culls (link, pixel) pairs by the link's pixel box and nearest depth; the
    result equals casting every edge pixel against every link and keeping the nearest hit, bit for bit."""
    make, data = frames
    seg = make()
    casters = seg._link_casters()
    captured = []
    orig = seg._refine_silhouette

    def grab(core, Tcl, boxes):
        out = orig(core, Tcl, boxes)
        captured.append((core, Tcl, out))
        return out

    seg._refine_silhouette = grab
    for _depth, q, _gt in data[:4]:
        seg.render_hand_depth(seg.kin.link_poses(q))
    assert len(captured) == 4
    d = np.stack([seg._rx, seg._ry, np.ones_like(seg._rx)], axis=-1).reshape(-1, 3)
    for core, Tcl, out in captured:
        changed = out != core
        assert changed.sum() > 20  # the splat's edges were re-decided
        ref = np.full(len(d), np.inf)  # every pixel against every link
        for link, T in Tcl.items():
            if link in casters:
                R, o = T[:3, :3], T[:3, 3]
                ref = np.minimum(ref, casters[link].hit_distance(-(R.T @ o), d @ R))
        ref = ref.reshape(core.shape)
        np.testing.assert_array_equal(out[changed], ref[changed])


@pytest.fixture(scope="module")
def medium_frames(shared_data):
    """(segmenter, [(depth, q, gt, visible_fraction)]) of a 0.5 s session seen with medium occlusion."""
    from vtrack.bench.segmentation import gt_mask_field, segmenter_for_session
    from vtrack.io.session import open_session
    from vtrack.testing.sim import tiny_session_path

    r = open_session(tiny_session_path(occlusion="medium", seconds=0.5))
    s = r["camera/cam0"]
    gts, gtf = gt_mask_field(r, "cam0")
    J = r["joints"]
    seg = segmenter_for_session(r, "cam0", STRIDE)
    out = []
    for i in range(len(s)):
        depth = (s["depth"][i][::STRIDE, ::STRIDE] * float(s.attrs["depth_scale"])).astype(np.float32)
        q = seg.kin.reorder(J.sample("q", np.array([s.t[i]]), mode="linear")[0], J.attrs["joint_names"])
        out.append((depth, q, gts[gtf][i][::STRIDE, ::STRIDE].astype(bool), float(gts["visible_fraction"][i])))
    return seg, out


def test_medium_occlusion_object_between_fingers(medium_frames):
    """The soup can seen between the fingers (split into strips by them) is segmented whole."""
    seg, data = medium_frames
    ious, left = [], []
    for depth, q, gt, vis in data:
        res = seg.segment(depth, q)
        if vis < 0.1 or not gt.any():
            continue
        ious.append(_iou(res.mask, gt))
        hand = (depth > 0) & ~gt
        left.append((res.mask & hand).sum() / hand.sum())
    assert len(ious) >= 10
    # measured on the 1 s session: median 0.878 (0.713 before the exact silhouette and finger-wide merge)
    assert np.median(ious) > 0.83
    assert np.mean(left) < 0.01


def test_object_split_by_a_wide_finger_band_is_merged_but_a_distractor_is_not():
    """Seen from above (medium occlusion) a curled finger hides a band ~40 mm wide across a banana or a mug: the
    two visible parts are one object (merge gap 50 mm; with 35 mm half the object was dropped, 5 s sessions:
    median IoU banana 0.65 -> 0.93, mug 0.58 -> 0.88). A separate thing 60 mm away is not merged."""
    from vtrack.frames.segmentation import HandAwareSegmenter, SegmentationOptions
    from vtrack.geometry.camera import PinholeCamera

    cam = PinholeCamera(120, 90, 140.0, 140.0, 60.0, 45.0)  # 3.2 mm per pixel at 0.45 m
    z0 = 0.45
    rr, cc = np.mgrid[0:90, 0:120]
    x, y = (cc - 60.0) * z0 / 140.0, (rr - 45.0) * z0 / 140.0
    left = (x > -0.06) & (x < -0.02) & (np.abs(y) < 0.03)
    right = (x > 0.02) & (x < 0.06) & (np.abs(y) < 0.03)  # 40 mm of finger between them (no depth there)
    distractor = (np.abs(x) < 0.012) & (y > 0.09) & (y < 0.115)  # 60 mm beyond the object's edge
    depth = np.where(left | right | distractor, z0, 1.0).astype(np.float32)  # a wall 1 m away behind
    contacts = np.array([[-0.045, 0.0, z0], [-0.035, 0.01, z0]])
    sensors = np.array([[-0.04, 0.0, z0 - 0.02], [0.04, 0.0, z0 - 0.02]])

    def mask(gap: float) -> np.ndarray:
        seg = HandAwareSegmenter(None, cam, np.eye(4), SegmentationOptions(merge_gap_m=gap))
        return seg.segment(depth, None, contacts_world=contacts, sensor_positions_world=sensors).mask

    m = mask(SegmentationOptions().merge_gap_m)
    assert m[left].all() and m[right].all()
    assert not m[distractor].any() and not m[depth == 1.0].any()
    old = mask(0.035)  # the previous gap keeps only the touched half
    assert old[left].all() and not old[right].any()


def test_hand_samples_do_not_depend_on_which_camera_asked_first(frames):
    """Spacings that share a cache key get the same hand samples in either order (they used to be sampled at the
    first caller's spacing, so a session's masks, and SLAM on them, depended on the sessions run before it)."""
    from vtrack.frames import segmentation as sg

    kin = frames[0]().kin
    got = []
    for order in ((0.00104, 0.00096), (0.00096, 0.00104)):
        sg._SAMPLE_CACHE.clear()
        got.append([sg.sample_link_surfaces(kin, sp, 400_000) for sp in order])
    sg._SAMPLE_CACHE.clear()
    links = sorted(got[0][0])
    assert links and all(len(got[0][0][k]) > 0 for k in links)
    for x in (got[0][1], got[1][0], got[1][1]):
        assert sorted(x) == links
        assert all(np.array_equal(x[k], got[0][0][k]) for k in links)


def test_grid_components_are_scipys_components(frames):
    """The clusters' connected components (OpenCV on the doubled grid) carry the labels of the sparse-graph
    components, numbering included (the cluster scores' ties are broken by it), on the depth graphs the
    segmenter builds from real frames and on random graphs."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from vtrack.frames.segmentation import grid_components

    make, data = frames
    seg = make()
    graphs = []
    orig = grid_components

    def reference(nodes, right, down):
        rows, cols = np.nonzero(nodes)
        idx = np.full(nodes.shape, -1, np.int64)
        idx[rows, cols] = np.arange(len(rows))
        s = np.concatenate([idx[:, :-1][right], idx[:-1][down]])
        t = np.concatenate([idx[:, 1:][right], idx[1:][down]])
        g = coo_matrix((np.ones(len(s), np.int8), (s, t)), shape=(len(rows), len(rows)))
        return connected_components(g, directed=False), rows, cols

    import vtrack.frames.segmentation as segmentation

    def grab(nodes, right, down, rows, cols):
        graphs.append((nodes, right, down))
        return orig(nodes, right, down, rows, cols)

    segmentation.grid_components = grab
    try:
        for depth, q, _gt in data:
            seg.segment(depth, q)
    finally:
        segmentation.grid_components = orig
    assert len(graphs) == len(data)
    rng = np.random.default_rng(2)
    for H, W in ((1, 9), (7, 1), (13, 17), (40, 31)):
        nodes = rng.random((H, W)) < 0.6
        right = nodes[:, :-1] & nodes[:, 1:] & (rng.random((H, W - 1)) < 0.6)
        down = nodes[:-1] & nodes[1:] & (rng.random((H - 1, W)) < 0.6)
        graphs.append((nodes, right, down))
    for nodes, right, down in graphs:
        (n_ref, lab_ref), rows, cols = reference(nodes, right, down)
        n, lab = orig(nodes, right, down, rows, cols)
        assert n == n_ref and lab.dtype == lab_ref.dtype
        np.testing.assert_array_equal(lab, lab_ref)
    assert max(int(np.max(orig(*g, *np.nonzero(g[0]))[1])) for g in graphs[: len(data)]) >= 3  # several clusters


def test_place_link_samples_is_the_per_link_transform_bit_for_bit(frames):
    """The batched sample placement gives exactly the per-link ``S @ R.T + t`` values, on the real hand
    samples at the session's link poses and on random poses (empty links included)."""
    from vtrack.frames.segmentation import place_link_samples

    make, data = frames
    seg = make()
    rng = np.random.default_rng(3)
    cases = []
    for _depth, q, _gt in data:
        poses = seg.kin.link_poses(q)
        Tcl = {k: seg.T_camera_world @ (v[0] if v.ndim == 3 else v) for k, v in poses.items()}
        seg.render_hand_depth(poses)
        samples = seg._samples
        cases.append(([samples[k] for k in samples if k in Tcl], [Tcl[k] for k in samples if k in Tcl]))
    for n in (0, 1, 3):
        S = [rng.normal(size=(m, 3)) for m in rng.integers(0, 50, size=n)] + [np.zeros((0, 3))]
        Ts = []
        for _ in S:
            T = np.eye(4)
            T[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
            T[:3, 3] = rng.normal(size=3)
            Ts.append(T)
        cases.append((S, Ts))
    for S, Ts in cases:
        counts = np.array([len(s) for s in S], np.int64)
        want = np.concatenate([s @ T[:3, :3].T + T[:3, 3] for s, T in zip(S, Ts, strict=True)])
        got = place_link_samples(np.concatenate(S), counts, np.repeat(np.arange(len(S)), counts), Ts)
        assert got.dtype == np.float64 and np.array_equal(got, want)
    assert len(cases[0][0]) > 10 and sum(len(s) for s in cases[0][0]) > 1000


def test_colour_mask_grows_into_dropouts_and_along_the_hand_never_into_it(frames):
    """Opt-in ``colour_grow_px``: the colour tracks' mask is the object mask plus, within that many pixels of it, the
    depth-less pixels and those beside the exact hand silhouette; never grown into the silhouette itself."""
    import cv2

    make, data = frames
    assert make().segment(*data[0][:2]).colour_mask is None  # off by default: the object mask is used
    seg = make(_opts(colour_grow_px=1))
    added_total, added_object = 0, 0
    for depth, q, gt in data:
        res = seg.segment(depth, q)
        cm = res.colour_mask
        assert cm is not None and cm.shape == res.mask.shape and cm.dtype == bool
        assert np.all(cm[res.mask])  # a superset of the object mask
        core, _ = seg.render_hand_depth(seg.kin.link_poses(q), with_core=True)
        core = np.isfinite(core)
        added = cm & ~res.mask
        assert not np.any(added & core)  # never into the hand (object pixels in front of it are in the object mask)
        near_mask = cv2.dilate(res.mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        near_hand = cv2.dilate(core.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        assert np.all(near_mask[added])  # one pixel of growth
        assert np.all(((depth <= 0) | near_hand)[added])  # only into dropouts or beside the hand
        added_total += int(added.sum())
        added_object += int((added & gt).sum())
    assert added_total > 0
    print(f"grown pixels: {added_total}, on the object (GT): {added_object}")
