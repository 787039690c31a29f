"""Offscreen screenshots (pyvista) of the same scene the browser viewer shows.

:func:`render_result` is what ``vtrack view --screenshot``, ``vtrack reconstruct``, ``vtrack track``
and ``vtrack demo`` call to put a picture into a result folder. The 3D view (world frame, z up) holds
the fused cloud (coloured by modality by default), the reconstructed mesh, the GT mesh (translucent
green), the hand posed by FK, tactile sensor frames, camera frusta and the object trajectories
(green GT, red estimate); the current tactile panels (image | GT height | GT contact) are stacked in
a column on the right.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.viz.data import DEFAULT_MAX_POINTS, ViewData
from vtrack.viz.viewer import EST_TRAJ_RGB, GT_MESH_RGB, GT_TRAJ_RGB, HAND_RGB, MESH_RGB, default_view


def parse_size(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (W, H) px, each in 64..8192."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise InputError("bad image size", field="--size", expected="WxH, e.g. 1280x960", got=text) from None
    if not (64 <= w <= 8192 and 64 <= h <= 8192):
        raise InputError("image size out of range", field="--size", expected="64..8192 px per side", got=text)
    return w, h


def _faces_pv(F: np.ndarray) -> np.ndarray:
    return np.hstack([np.full((len(F), 1), 3, np.int64), F.astype(np.int64)]).ravel()


def _transform(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    V = np.asarray(V, np.float64)
    return V @ T[:3, :3].T + T[:3, 3]


def _lines(segments: np.ndarray):
    """pyvista PolyData of (N, 2, 3) line segments."""
    import pyvista as pv

    P = np.asarray(segments, np.float64).reshape(-1, 3)
    n = len(P) // 2
    cells = np.column_stack([np.full(n, 2), np.arange(0, 2 * n, 2), np.arange(1, 2 * n, 2)]).ravel()
    return pv.PolyData(P, lines=cells)


def _frustum_segments(cam, depth: float) -> np.ndarray:
    """Frustum edges of a camera (OpenCV frame) as world-frame segments, ``depth`` m deep."""
    K, w, h = cam.K, cam.width, cam.height
    corners = []
    for u, v in ((0, 0), (w, 0), (w, h), (0, h)):
        corners.append([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth])
    C = _transform(np.array(corners), cam.T_world_camera)
    o = cam.T_world_camera[:3, 3]
    segs = [[o, c] for c in C] + [[C[k], C[(k + 1) % 4]] for k in range(4)]
    return np.array(segs)


def render_scene(
    data: ViewData, frame: int = -1, size: tuple[int, int] = (1280, 960), color_mode: str = "modality"
) -> np.ndarray:
    """Render ``data`` at timeline ``frame`` (negative counts from the end) to an (H, W', 3) uint8 image
    (W' = W plus the tactile panel column when the session has tactile streams)."""
    import pyvista as pv

    n = data.n_frames
    i = frame % n if frame < 0 else min(frame, n - 1)
    st = data.frame(i)
    T_obj = data.object_pose(st, "estimate")
    p = pv.Plotter(off_screen=True, window_size=list(size))
    p.set_background("white")
    lo, hi = data.bounds()
    scale = max(float(np.linalg.norm(hi - lo)), 0.05)
    if data.cloud is not None:
        cnt = data.cloud.count_until(st.t) if data.cloud.has_time else len(data.cloud)
        cnt = max(cnt, 1)
        P = data.cloud.points[:cnt].astype(np.float64)
        if data.recon_frame == "object":
            P = _transform(P, T_obj)
        mode = color_mode if color_mode in data.cloud.colors else "modality"
        pc = pv.PolyData(P)
        pc["rgb"] = data.cloud.colors[mode][:cnt]
        p.add_mesh(pc, scalars="rgb", rgb=True, point_size=3, render_points_as_spheres=False)
    if data.mesh is not None:
        V = data.mesh[0] if data.recon_frame == "world" else _transform(data.mesh[0], T_obj)
        p.add_mesh(
            pv.PolyData(np.asarray(V, np.float64), _faces_pv(data.mesh[1])),
            color=np.array(MESH_RGB) / 255,
            smooth_shading=True,
        )
    if data.gt_mesh is not None and st.T_world_object_gt is not None:
        V = _transform(data.gt_mesh[0], st.T_world_object_gt)
        p.add_mesh(pv.PolyData(V, _faces_pv(data.gt_mesh[1])), color=np.array(GT_MESH_RGB) / 255, opacity=0.3)
    for link, meshes in data.link_meshes.items():
        if link not in st.link_poses:
            continue
        for V, F in meshes:
            p.add_mesh(
                pv.PolyData(_transform(V, st.link_poses[link]), _faces_pv(F)),
                color=np.array(HAND_RGB) / 255,
                opacity=0.8,
            )
    axis_len = 0.012
    for Ts in st.sensor_poses.values():
        o = Ts[:3, 3]
        for k, rgb in enumerate(((1, 0, 0), (0, 0.7, 0), (0, 0, 1))):
            p.add_mesh(_lines(np.array([[o, o + Ts[:3, k] * axis_len]])), color=rgb, line_width=3)
    for cam in data.cameras:
        p.add_mesh(_lines(_frustum_segments(cam, min(0.04, 0.3 * scale))), color=(0.16, 0.35, 0.8), line_width=2)
    for T, rgb in ((data.gt_T, GT_TRAJ_RGB), (data.est["T_est"] if data.est is not None else None, EST_TRAJ_RGB)):
        if T is None:
            continue
        P = T[:, :3, 3]
        ok = np.isfinite(P).all(1)
        seg = ok[:-1] & ok[1:]
        if seg.any():
            p.add_mesh(_lines(np.stack([P[:-1][seg], P[1:][seg]], axis=1)), color=np.array(rgb) / 255, line_width=3)
    pos, look, up = default_view(data)
    p.camera_position = [tuple(pos), tuple(look), tuple(up)]
    p.camera.view_angle = 50.0
    p.add_text(f"t = {st.t:.3f} s  frame {i + 1}/{n}", position="upper_left", font_size=10, color="black")
    if data.cloud is not None and color_mode == "modality":
        p.add_text("cloud: vision blue, touch orange", position="lower_left", font_size=8, color="black")
    img = np.asarray(p.screenshot(return_img=True))[..., :3].copy()
    p.close()
    return _with_panels(img, st.panels)


def _with_panels(img: np.ndarray, panels: dict[str, np.ndarray]) -> np.ndarray:
    """Append the tactile panels as a column on the right (scaled to fit the image height)."""
    if not panels:
        return img
    import cv2

    H = img.shape[0]
    rows = list(panels.values())
    gap, label_h = 6, 18
    row_h = max(8, min(H // 4, (H - (gap + label_h) * len(rows) - gap) // len(rows)))
    scaled = []
    for name, r in panels.items():
        s = cv2.resize(r, (max(1, round(r.shape[1] * row_h / r.shape[0])), row_h), interpolation=cv2.INTER_NEAREST)
        lab = np.full((label_h, s.shape[1], 3), 255, np.uint8)
        cv2.putText(lab, name, (2, label_h - 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        scaled.append(np.concatenate([lab, s], axis=0))
    W = max(s.shape[1] for s in scaled) + 2 * gap
    col = np.full((H, W, 3), 255, np.uint8)
    y = gap
    for s in scaled:
        if y + s.shape[0] > H:
            break
        col[y : y + s.shape[0], gap : gap + s.shape[1]] = s
        y += s.shape[0] + gap
    return np.concatenate([img, col], axis=1)


def render_result(
    path: str | Path,
    out_png: str | Path,
    frame: int = -1,
    size: tuple[int, int] = (1280, 960),
    max_points: int = DEFAULT_MAX_POINTS,
    color_mode: str = "modality",
) -> Path:
    """Render a session / result folder (anything ``vtrack view`` accepts) to ``out_png``.

    Raises:
        InputError: bad path or incomplete result folder; unwritable output.
    """
    import cv2

    data = ViewData(path, max_points=max_points)
    img = render_scene(data, frame=frame, size=size, color_mode=color_mode)
    out = Path(out_png)
    if out.suffix.lower() != ".png":
        raise InputError("screenshot must be a .png file", path=out, expected=".png")
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), np.ascontiguousarray(img[..., ::-1])):
        raise InputError("cannot write the screenshot", path=out)
    return out


def save_mesh_cloud_screenshot(
    path: str | Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    cloud: Any = None,
    title: str = "",
    gt_path: Path | None = None,
    size: tuple[int, int] = (900, 600),
) -> Path:
    """Off-screen pyvista render of a reconstruction result alone (no session needed): mesh (object or world
    frame, as given), optional GT mesh file as a wireframe, vision (blue) / touch (red) points of a fused cloud."""
    import pyvista as pv

    pl = pv.Plotter(off_screen=True, window_size=size)
    if len(faces):
        fa = np.hstack([np.full((len(faces), 1), 3), faces]).astype(np.int64).ravel()
        pl.add_mesh(pv.PolyData(np.asarray(vertices), fa), color="lightgray", smooth_shading=True)
    if gt_path is not None:
        gt = pv.read(str(gt_path))
        pl.add_mesh(gt, style="wireframe", color="green", opacity=0.15)
    if cloud is not None and len(cloud):
        from vtrack.fusion.cloud import TOUCH

        rng = np.random.default_rng(0)
        for mod, colour in ((0, "royalblue"), (TOUCH, "red")):
            P = cloud.xyz[cloud.modality == mod]
            if len(P) > 20000:
                P = P[rng.choice(len(P), 20000, replace=False)]
            if len(P):
                pl.add_points(P, color=colour, point_size=2 if mod == 0 else 3, render_points_as_spheres=False)
    pl.add_text(title, font_size=10)
    pl.view_isometric()
    pl.screenshot(str(path))
    pl.close()
    return Path(path)
