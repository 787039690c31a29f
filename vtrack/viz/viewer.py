"""Interactive browser viewer (viser) for sessions, reconstructions and tracking results.

The page is served by viser's bundled single-file client from localhost: no internet is needed.

Scene tree (world frame, z up, metres):

- ``/object`` at the current object pose (estimate or GT, GUI choice): reconstructed mesh and
  fused cloud when they are in the object frame; ``/recon`` (identity) when they are in the world frame;
- ``/object_gt`` at the GT pose: the GT mesh (translucent green);
- ``/hand/<link>``: hand visual meshes, posed by forward kinematics of the session's joint angles;
- ``/sensors/<name>``: tactile sensor frames (x = image columns, z = gel normal);
- ``/cameras/<name>``: camera frusta with the current RGB frame;
- ``/trajectory/{gt,estimate}``: object position over the whole session (green GT, red estimate).

The fused cloud is split into time-ordered bins (one viser node each): scrubbing the timeline
toggles whole bins and re-sends only the one bin that straddles the current time, so a frame update
costs O(bin) instead of O(cloud). Frame updates run on a worker thread that always renders the
latest requested frame (requests arriving while busy are coalesced, so dragging never queues up).
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from vtrack.viz.colors import COLOR_MODES
from vtrack.viz.data import DEFAULT_MAX_POINTS, ViewData

MESH_RGB = (200, 200, 210)
GT_MESH_RGB = (60, 200, 90)
HAND_RGB = (165, 165, 175)
GT_TRAJ_RGB = (40, 170, 70)
EST_TRAJ_RGB = (220, 40, 40)


_LOOPBACK_NAMES = {"127.0.0.1", "localhost", "::1", "[::1]"}


def request_allowed(headers: object, bound_host: str) -> tuple[bool, str]:
    """Is an HTTP/websocket request to the viewer from an allowed page? (allowed, reason if not).

    viser accepts websocket connections from any web page, so a page open in the same browser could
    read the scene while ``vtrack view`` runs. Two checks close that (the same ones Jupyter makes):

    - ``Host`` must name the address the server is bound to (a loopback name when bound to
      127.0.0.1): a DNS-rebinding page (``evil.example`` resolving to 127.0.0.1) fails this;
    - a browser's ``Origin``, when sent, must be the viewer's own ``http://<Host>``: a
      cross-site page's websocket fails this. Non-browser clients send no Origin and pass.
    """
    get = getattr(headers, "get", None)
    host_hdr = (get("Host") if get else None) or ""
    origin = (get("Origin") if get else None) or ""
    name = host_hdr.rsplit(":", 1)[0] if not host_hdr.startswith("[") else host_hdr.split("]")[0] + "]"
    if bound_host in ("127.0.0.1", "localhost", "::1"):
        if name.lower() not in _LOOPBACK_NAMES:
            return False, f"Host {host_hdr!r} is not a loopback address"
    if origin and origin.lower() not in ("null",) and origin.lower() != f"http://{host_hdr}".lower():
        return False, f"cross-origin request from {origin!r}"
    if origin.lower() == "null":  # sandboxed iframes / file:// pages
        return False, "request from an opaque (null) origin"
    return True, ""


class _origin_checked_serve:
    """Context manager: while viser starts its server, wrap its ``process_request`` with
    :func:`request_allowed` (viser has no option for it). Rejected requests get HTTP 403."""

    def __init__(self, bound_host: str) -> None:
        self.bound_host = bound_host

    def __enter__(self) -> _origin_checked_serve:
        import websockets.asyncio.server as wss

        self._wss = wss
        self._orig = wss.serve
        bound = self.bound_host

        def serve(*args, process_request=None, **kw):  # noqa: ANN001, ANN202 (mirrors websockets.serve)
            def checked(connection, request):  # noqa: ANN001, ANN202
                ok, why = request_allowed(request.headers, bound)
                if not ok:
                    return connection.respond(403, f"vtrack view: forbidden ({why})\n")
                return process_request(connection, request) if process_request else None

            return self._orig(*args, process_request=checked, **kw)

        wss.serve = serve
        return self

    def __exit__(self, *exc: object) -> None:
        self._wss.serve = self._orig


def wxyz_position(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """viser pose of a 4x4 transform: quaternion (w, x, y, z) and translation (m)."""
    from vtrack.geometry.se3 import matrix_to_quat

    q = matrix_to_quat(np.asarray(T[:3, :3], np.float64))  # (x, y, z, w)
    return np.array([q[3], q[0], q[1], q[2]]), np.asarray(T[:3, 3], np.float64)


def wxyz_position_batch(Ts: np.ndarray) -> np.ndarray:
    """(N, 4) viser quaternions (w, x, y, z) of (N, 4, 4) transforms."""
    from vtrack.geometry.se3 import matrix_to_quat

    q = matrix_to_quat(np.asarray(Ts, np.float64)[:, :3, :3])
    return np.concatenate([q[:, 3:], q[:, :3]], axis=1)


def default_view(
    data: ViewData, bounds: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A camera ``(position, look_at, up)`` that frames the content from the front-right, above."""
    lo, hi = data.bounds() if bounds is None else bounds
    centre = 0.5 * (lo + hi)
    radius = max(float(np.linalg.norm(hi - lo)) * 0.5, 0.03)
    d = np.array([1.0, -0.8, 0.7])
    d /= np.linalg.norm(d)
    return centre + d * radius * 2.6, centre, np.array([0.0, 0.0, 1.0])


class _CloudBins:
    """The fused cloud as ``n_bins`` time-ordered point-cloud nodes (see module docstring)."""

    def __init__(self, scene, parent: str, cloud, mode: str, point_size: float, n_bins: int = 32) -> None:
        self.cloud = cloud
        self.mode = mode
        n = len(cloud)
        n_bins = max(1, min(n_bins, n // 2000 or 1))
        self.edges = np.linspace(0, n, n_bins + 1).round().astype(np.int64)
        self.shown = [0] * n_bins
        self.handles = []
        cols = self._colors(mode)
        # Half precision halves what the browser downloads and parses; its step is <= 2 mm within 4 m
        # of the origin (0.03 mm for object-frame clouds), far below the point size.
        extent = float(np.abs(cloud.points).max()) if n else 0.0
        self.precision = "float16" if extent < 4.0 else "float32"
        for k in range(n_bins):
            a, b = self.edges[k], self.edges[k + 1]
            self.handles.append(
                scene.add_point_cloud(
                    f"{parent}/cloud/bin{k:03d}",
                    cloud.points[a:b],
                    cols[a:b],
                    point_size=point_size,
                    point_shape="rounded",
                    precision=self.precision,
                )
            )
            self.shown[k] = b - a

    def _colors(self, mode: str) -> np.ndarray:
        # Sent as they are: with plain lights viser shows point colours unchanged (an HDRI environment
        # map, --hdri, tone-maps them lighter).
        return self.cloud.colors[mode]

    def show_until(self, n: int) -> int:
        """Show the first ``n`` (time-sorted) points; returns the number of points re-sent."""
        sent = 0
        cols = self._colors(self.mode)
        for k, h in enumerate(self.handles):
            a, b = int(self.edges[k]), int(self.edges[k + 1])
            want = int(np.clip(n - a, 0, b - a))
            if want == 0:
                if h.visible:
                    h.visible = False
                continue
            if want != self.shown[k]:
                # Points and colours change length together (sent in one atomic batch).
                h.points = self.cloud.points[a : a + want]
                h.colors = cols[a : a + want]
                self.shown[k] = want
                sent += want
            if not h.visible:
                h.visible = True
        return sent

    def set_mode(self, mode: str) -> None:
        if mode not in self.cloud.colors or mode == self.mode:
            return
        self.mode = mode
        cols = self._colors(mode)
        for k, h in enumerate(self.handles):
            a = int(self.edges[k])
            h.colors = cols[a : a + self.shown[k]]

    def set_point_size(self, size: float) -> None:
        for h in self.handles:
            h.point_size = size

    def set_visible(self, visible: bool, n: int) -> None:
        if visible:
            for k in range(len(self.handles)):
                self.handles[k].visible = self.shown[k] > 0 and int(self.edges[k]) < n
        else:
            for h in self.handles:
                h.visible = False


class Viewer:
    """A running viser server showing one :class:`ViewData`.

    Args:
        data: what to show.
        host, port: where to serve (viser moves to the next free port if ``port`` is taken;
            :attr:`port` is the one bound; 0 picks any free port).
        log: where connection/readiness messages go (default: stderr).
    """

    def __init__(
        self,
        data: ViewData,
        host: str = "127.0.0.1",
        port: int = 8080,
        log: Callable[[str], None] | None = None,
        hdri: bool = False,
    ) -> None:
        import viser

        self.data = data
        self.log = log or (lambda m: print(f"vtrack view: {m}", file=sys.stderr, flush=True))
        t0 = time.perf_counter()
        with _origin_checked_serve(host):
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.scene.set_up_direction("+z")
        if not hdri:
            # Plain lights, no image-based lighting and no shadows: the HDRI environment map costs tens
            # of seconds to prepare in software WebGL (machines without a GPU, headless browsers).
            self.server.scene.configure_environment_map(None)
            self.server.scene.configure_default_lights(True, cast_shadow=False)
        self.frame_ms: list[float] = []
        self._lock = threading.Lock()
        self._cond = threading.Condition()
        self._pending: int | None = None
        self._busy = False
        self._stop = threading.Event()
        self._playing = threading.Event()
        self._build_scene()
        self._build_gui()
        pos, look, up = default_view(data, self._bounds)
        cam = self.server.initial_camera
        cam.position = tuple(pos)
        cam.look_at = tuple(look)
        cam.up = tuple(up)

        @self.server.on_client_connect
        def _(client) -> None:
            self.log(f"client {client.client_id} connected")

        @self.server.on_client_disconnect
        def _(client) -> None:
            self.log(f"client {client.client_id} disconnected")

        self.update_frame(n_last := data.n_frames - 1)
        self.log(f"showing frame {n_last + 1}/{data.n_frames}")
        self._worker = threading.Thread(target=self._work, name="vtrack-view-frames", daemon=True)
        self._worker.start()
        self._player = threading.Thread(target=self._play, name="vtrack-view-play", daemon=True)
        self._player.start()
        self._filler = threading.Thread(target=self._fill_cache, name="vtrack-view-cache", daemon=True)
        self._filler.start()
        self.startup_s = time.perf_counter() - t0

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        host = self.server.get_host()
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '::') else host}:{self.port}"

    # -- scene ---------------------------------------------------------------------------------
    def _build_scene(self) -> None:
        d, sc = self.data, self.server.scene
        obj = "/object" if d.recon_frame == "object" else "/recon"
        self.obj_node = sc.add_frame("/object", show_axes=True, axes_length=0.03, axes_radius=0.0012)
        if obj == "/recon":
            sc.add_frame("/recon", show_axes=False)
        self.gt_node = sc.add_frame(
            "/object_gt", show_axes=True, axes_length=0.02, axes_radius=0.0008, visible=d.gt_T is not None
        )
        self.mesh = None
        if d.mesh is not None:
            self.mesh = sc.add_mesh_simple(f"{obj}/mesh", d.mesh[0], d.mesh[1], color=MESH_RGB, side="double")
        self.gt_mesh = None
        if d.gt_mesh is not None:
            self.gt_mesh = sc.add_mesh_simple(
                "/object_gt/mesh",
                d.gt_mesh[0],
                d.gt_mesh[1],
                color=GT_MESH_RGB,
                opacity=0.35,
                visible=d.mesh is None and d.cloud is None,
            )
        self._bounds = d.bounds()
        self.point_size = self._default_point_size()
        self.bins = None
        if d.cloud is not None:
            self.bins = _CloudBins(sc, obj, d.cloud, "modality", self.point_size)
        self.hand_nodes = {}
        for link, meshes in d.link_meshes.items():
            self.hand_nodes[link] = sc.add_frame(f"/hand/{link}", show_axes=False)
            for j, (V, F) in enumerate(meshes):
                sc.add_mesh_simple(f"/hand/{link}/m{j}", V, F, color=HAND_RGB, opacity=0.8)
        self.sensor_nodes = {}
        sensor_names = list(d.hand.sensor_names) if d.hand is not None else []
        for s in sensor_names:
            self.sensor_nodes[s] = sc.add_frame(f"/sensors/{s}", axes_length=0.012, axes_radius=0.0007)
        self.cam_frusta = {}
        for c in d.cameras:
            q, p = wxyz_position(c.T_world_camera)
            self.cam_frusta[c.name] = sc.add_camera_frustum(
                f"/cameras/{c.name}",
                fov=c.fov_y,
                aspect=c.width / c.height,
                scale=0.04,
                thickness=0.0015,
                color=(40, 90, 200),
                wxyz=q,
                position=p,
            )
        self.traj = {}
        if d.gt_T is not None:
            self.traj["gt"] = self._trajectory("/trajectory/gt", d.gt_T, GT_TRAJ_RGB)
        if d.est is not None:
            self.traj["estimate"] = self._trajectory("/trajectory/estimate", d.est["T_est"], EST_TRAJ_RGB)

    def _trajectory(self, name: str, T: np.ndarray, rgb: tuple[int, int, int]):
        P = T[:, :3, 3]
        ok = np.isfinite(P).all(1)
        seg_ok = ok[:-1] & ok[1:]
        if not seg_ok.any():
            return None
        segs = np.stack([P[:-1][seg_ok], P[1:][seg_ok]], axis=1).astype(np.float32)
        return self.server.scene.add_line_segments(name, segs, rgb, thickness=0.0015)

    def _default_point_size(self) -> float:
        lo, hi = self._bounds
        return float(np.clip(np.linalg.norm(hi - lo) / 250.0, 0.0005, 0.01))

    # -- GUI -----------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        d, gui = self.data, self.server.gui
        n = d.n_frames
        with gui.add_folder("Timeline"):
            # Start at the last frame: the complete result is what one wants to see first.
            self.slider = gui.add_slider("frame", min=0, max=max(n - 1, 1), step=1, initial_value=n - 1, disabled=n < 2)
            self.time_md = gui.add_markdown("t = 0.000 s")
            self.play_btn = gui.add_button("Play", disabled=n < 2)
            self.steps = gui.add_button_group("step", ["|<", "<", ">", ">|"])
            self.fps = gui.add_slider("playback fps", min=1, max=60, step=1, initial_value=20)
        with gui.add_folder("Display"):
            modes = [m for m in COLOR_MODES if d.cloud is not None and m in d.cloud.colors] or ["modality"]
            self.color_dd = gui.add_dropdown("colour cloud by", modes, initial_value=modes[0])
            self.accumulate = gui.add_checkbox(
                "cloud up to current time", initial_value=bool(d.cloud is not None and d.cloud.has_time)
            )
            self.psize = gui.add_slider(
                "point size (mm)", min=0.2, max=10.0, step=0.1, initial_value=round(self.point_size * 1000, 1)
            )
            self.pose_dd = gui.add_dropdown(
                "object pose", ["estimate", "gt"], initial_value="estimate" if d.est is not None else "gt"
            )
            self.cb = {}
            for key, on in (
                ("cloud", d.cloud is not None),
                ("mesh", d.mesh is not None),
                ("GT mesh", d.gt_mesh is not None and d.mesh is None and d.cloud is None),
                ("hand", bool(self.hand_nodes)),
                ("sensor frames", bool(self.sensor_nodes)),
                ("cameras", bool(self.cam_frusta)),
                ("camera images", bool(self.cam_frusta)),
                ("trajectories", bool(self.traj)),
            ):
                self.cb[key] = gui.add_checkbox(f"show {key}", initial_value=on)
        self.panel_images = {}
        if d.tactile or d.cameras:
            with gui.add_folder("Sensors"):
                gui.add_markdown(f"tactile: image | GT height (0-{d.height_vmax_mm:.1f} mm) | GT contact")
                st = d.frame(n - 1)
                for name, img in st.panels.items():
                    self.panel_images[name] = gui.add_image(img, label=name, format="jpeg", jpeg_quality=85)
                for name, img in st.camera_images.items():
                    self.panel_images[f"camera/{name}"] = gui.add_image(
                        img, label=f"camera {name}", format="jpeg", jpeg_quality=80
                    )
        with gui.add_folder("Info", expand_by_default=False):
            s = d.summary()
            lines = [f"- **{k}**: {v}" for k, v in s.items() if v not in (None, [], 0, False)]
            lines += [f"- note: {m}" for m in d.notes]
            gui.add_markdown("\n".join(lines) or "(empty)")
            self.perf_md = gui.add_markdown("frame update: - ms")

        self.slider.on_update(lambda _: self.request_frame(int(self.slider.value)))
        self.play_btn.on_click(lambda _: self._toggle_play())
        self.steps.on_click(lambda ev: self._step(ev.target.value))
        self.color_dd.on_update(
            lambda _: self._with_lock(lambda: self.bins and self.bins.set_mode(self.color_dd.value))
        )
        self.accumulate.on_update(lambda _: self.request_frame(int(self.slider.value)))
        self.psize.on_update(
            lambda _: self._with_lock(lambda: self.bins and self.bins.set_point_size(self.psize.value / 1000.0))
        )
        self.pose_dd.on_update(lambda _: self.request_frame(int(self.slider.value)))
        for cb in self.cb.values():
            cb.on_update(lambda _: self._apply_visibility())
        self._apply_visibility()

    def _with_lock(self, fn: Callable[[], object]) -> None:
        with self._lock:
            fn()

    def _apply_visibility(self) -> None:
        with self._lock:
            c = {k: v.value for k, v in self.cb.items()}
            if self.mesh is not None:
                self.mesh.visible = c["mesh"]
            if self.gt_mesh is not None:
                self.gt_mesh.visible = c["GT mesh"]
            if self.bins is not None:
                n = self._cloud_count(int(self.slider.value))
                self.bins.set_visible(c["cloud"], n)
            for h in self.hand_nodes.values():
                h.visible = c["hand"]
            for h in self.sensor_nodes.values():
                h.visible = c["sensor frames"]
            for h in self.cam_frusta.values():
                h.visible = c["cameras"]
                if not c["camera images"] and h.image is not None:
                    h.image = None
            for h in self.traj.values():
                if h is not None:
                    h.visible = c["trajectories"]

    def _toggle_play(self) -> None:
        if self._playing.is_set():
            self._playing.clear()
            self.play_btn.label = "Play"
        else:
            self._playing.set()
            self.play_btn.label = "Pause"

    def _step(self, which: str) -> None:
        n, i = self.data.n_frames, int(self.slider.value)
        target = {"|<": 0, "<": i - 1, ">": i + 1, ">|": n - 1}.get(which, i)
        self.slider.value = int(np.clip(target, 0, n - 1))

    # -- frames --------------------------------------------------------------------------------
    def _cloud_count(self, i: int) -> int:
        d = self.data
        if d.cloud is None:
            return 0
        if self.accumulate.value and d.cloud.has_time:
            return d.cloud.count_until(float(d.times[int(np.clip(i, 0, d.n_frames - 1))]))
        return len(d.cloud)

    def request_frame(self, i: int) -> None:
        """Ask the worker to show frame ``i`` (latest request wins)."""
        with self._cond:
            self._pending = int(i)
            self._cond.notify()

    def wait_idle(self, timeout: float = 10.0) -> bool:
        """Block until no frame request is pending or being rendered."""
        end = time.monotonic() + timeout
        with self._cond:
            while self._pending is not None or self._busy:
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
        return True

    def _work(self) -> None:
        while not self._stop.is_set():
            with self._cond:
                while self._pending is None and not self._stop.is_set():
                    self._cond.wait(0.5)
                if self._stop.is_set():
                    return
                i, self._pending, self._busy = self._pending, None, True
            try:
                self.update_frame(i)
            except Exception as e:  # keep the viewer alive; show what went wrong
                self.log(f"frame {i} failed: {type(e).__name__}: {e}")
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()
            self._prefetch(i)

    def _prefetch(self, i: int) -> None:
        """Decode the images of the frames around ``i`` while idle (stops at the next request)."""
        n = self.data.n_frames
        for k in (1, 2, 3, 4, 5, 6, 7, 8, -1, -2, -3, -4, 9, 10, 11, 12):
            j = (i + k) % n
            if self._pending is not None or self._stop.is_set():
                return
            if not self.data.is_cached(j):
                try:
                    self.data.images(j)
                except Exception:  # a bad frame shows up (and is reported) when it is displayed
                    return

    def _fill_cache(self) -> None:
        """Decode every frame's images in the background (yielding to frame requests) until the cache
        budget is reached, so that playback and scrubbing never wait for the session store."""
        time.sleep(0.5)  # let the first client load the page first
        for j in range(self.data.n_frames):
            while (self._busy or self._pending is not None) and not self._stop.is_set():
                time.sleep(0.02)
            if self._stop.is_set() or self.data.image_cache_full:
                return
            if not self.data.is_cached(j):
                try:
                    self.data.images(j)
                except Exception:  # reported when the frame is displayed
                    return

    def _play(self) -> None:
        while not self._stop.is_set():
            if not self._playing.wait(0.2):
                continue
            t0 = time.perf_counter()
            self.wait_idle(5.0)
            n = self.data.n_frames
            self.slider.value = (int(self.slider.value) + 1) % n
            dt = 1.0 / max(float(self.fps.value), 1.0) - (time.perf_counter() - t0)
            if dt > 0:
                time.sleep(dt)

    def update_frame(self, i: int) -> float:
        """Show frame ``i`` now (poses, cloud prefix, panels); returns the server-side time in ms."""
        t0 = time.perf_counter()
        d = self.data
        st = d.frame(i)
        # All node poses of this frame, converted to quaternions in one batched call.
        nodes = [(self.obj_node, d.object_pose(st, self.pose_dd.value))]
        if st.T_world_object_gt is not None:
            nodes.append((self.gt_node, st.T_world_object_gt))
        nodes += [(h, st.link_poses[k]) for k, h in self.hand_nodes.items() if k in st.link_poses]
        nodes += [(h, st.sensor_poses[k]) for k, h in self.sensor_nodes.items() if k in st.sensor_poses]
        Ts = np.stack([T for _, T in nodes])
        quats = wxyz_position_batch(Ts)
        with self._lock, self.server.atomic():
            for (h, T), q in zip(nodes, quats, strict=True):
                h.wxyz, h.position = q, T[:3, 3]
            if self.bins is not None and self.cb["cloud"].value:
                self.bins.show_until(self._cloud_count(st.index))
            for name, img in st.panels.items():
                if name in self.panel_images:
                    self.panel_images[name].image = img
            for name, img in st.camera_images.items():
                key = f"camera/{name}"
                if key in self.panel_images:
                    self.panel_images[key].image = img
                if name in self.cam_frusta and self.cb["camera images"].value:
                    self.cam_frusta[name].image = img
            self.time_md.content = f"t = {st.t:.3f} s  (frame {st.index + 1}/{d.n_frames})"
        ms = (time.perf_counter() - t0) * 1e3
        self.frame_ms.append(ms)
        self.perf_md.content = f"frame update: {ms:.1f} ms (server side)"
        return ms

    # -- lifecycle -----------------------------------------------------------------------------
    def stop(self) -> None:
        self._stop.set()
        self._playing.clear()
        with self._cond:
            self._cond.notify_all()
        self.server.stop()


def serve(
    path: str | Path,
    host: str = "127.0.0.1",
    port: int = 8080,
    max_points: int = DEFAULT_MAX_POINTS,
    block: bool = True,
    log: Callable[[str], None] | None = None,
    hdri: bool = False,
) -> Viewer:
    """Load ``path`` and serve it; with ``block`` run until Ctrl-C.

    Raises:
        InputError: bad path or incomplete result folder (raised before the server starts).
    """
    t0 = time.perf_counter()
    data = ViewData(path, max_points=max_points)
    viewer = Viewer(data, host=host, port=port, log=log, hdri=hdri)
    viewer.log(
        f"ready in {time.perf_counter() - t0:.2f} s: {viewer.url}  "
        f"({data.n_frames} frames, {len(data.cloud) if data.cloud is not None else 0} cloud points shown)"
    )
    if not block:
        return viewer
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    return viewer
