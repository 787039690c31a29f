"""Live consumers: ``null`` (throughput check), ``track`` (tracking per camera frame through the frames
layer), ``reconstruct`` (TSDF integration per camera frame).

``track`` and ``reconstruct`` call the tracking / fusion engineers' per-frame APIs
(:meth:`vtrack.tracking.tracker.KnownShapeTracker.step`,
:meth:`vtrack.fusion.tsdf.TSDFReconstructor.integrate_depth`) on the newest data: joints and
tactile frames update state; each camera frame triggers one step.

Consumers are registry components (``live.<kind>``, :func:`make_consumer`); their options are typed
(:class:`LiveTrackConfig`, :class:`LiveReconstructConfig`) with the defaults set there.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.live.pipeline import Consumer
from vtrack.live.shared import FrameOverwritten
from vtrack.live.sources import FrameEvent
from vtrack.tracking.run import TRACK_TOUCH_DOWNSAMPLE, TRACK_TOUCH_STRIDE, colour_term_on


@dataclass
class LiveTrackConfig:
    """Options of :class:`TrackConsumer`: depth_stride = keep every k-th depth pixel (rows and columns);
    touch_worker = run the tactile pipeline on each tactile image as it arrives: ``process`` (a child
    process: tactile images and tracking on two cores), ``thread`` (a worker thread of this process; it
    shares the GIL with the tracker) or ``off`` (on the newest image of each sensor inside the camera
    frame's step, as offline tracking does; the step is then longer and the images in between are never
    read); frames_worker = where a camera frame is segmented and turned into the tracker's input, a stage of its
    own (frame k+1 is segmented while the tracker steps on frame k) in a child process: ``process`` (its own, the
    default; the newest contacts go with each frame), ``shared`` (the touch process's, which keeps its contacts), or
    ``inline`` (in the tracker's step); touch_downsample /
    touch_stride = the tactile pipeline's working-resolution factor and point stride (tracking's defaults,
    :data:`vtrack.tracking.run.TRACK_TOUCH_DOWNSAMPLE`); camera_stride = track every k-th camera frame (by
    time: a frame is tracked once k - 0.5 camera periods have passed since the last tracked one; the frames in
    between are neither segmented nor tracked); max_camera_stride = the stride the tracker may go up to while
    it falls behind: after each step the stride becomes ceil(recent step wall time / (track_budget x camera
    period)), between camera_stride and max_camera_stride, so the CPU it would spend on frames it cannot keep
    up with goes to the touch stage and the replay instead; colour = the colour term (see the field). The
    tracker's own options are :class:`vtrack.tracking.window.TrackerOptions` (passed through; ``colour_opts``:
    :class:`vtrack.tracking.colour.ColourOptions` overrides)."""

    depth_stride: int = 4
    touch_worker: str = "process"
    # its own process by default since 2026-11-28: over 9 paired runs (3 sessions x 3 rounds, `bench live`) it kept
    # up better than inline, real-time factor 1.06 vs 0.81 mean (>= 1 in 6 of 9 vs 1 of 9), camera frames dropped
    # 13.7 vs 22.6 %, tactile 0-2 % vs 0 %, at +14 ms latency (docs/benchmarks/live_frames_process.md). It was inline
    # before: on 2026-11-26 the four processes contended for the two cores (tactile drops 22-38 % vs 4-13 %), before
    # the tactile pipeline and the tracker step got cheaper
    frames_worker: str = "process"
    touch_downsample: int = TRACK_TOUCH_DOWNSAMPLE
    touch_stride: int = TRACK_TOUCH_STRIDE
    camera_stride: int = 1
    max_camera_stride: int = 1
    track_budget: float = 0.9
    #: the tracker's colour term (KLT feature tracks on each camera's RGB image, :mod:`vtrack.tracking.colour`,
    #: built by :meth:`vtrack.frames.session.SessionFrames.build`) when the tracker uses it (SLAM by default,
    #: :func:`vtrack.tracking.run.colour_term_on`): the replay then decodes the camera's ``rgb`` field too, and the
    #: tracks live in the process that builds the frames. Off: depth only (frames without ``colour_ids``)
    colour: bool = True


class CameraStride:
    """Which camera frames the tracker takes (:class:`LiveTrackConfig` camera_stride / max_camera_stride /
    track_budget): every k-th by time, k adapted to how long the tracker's steps take."""

    def __init__(self, stride: int, max_stride: int, budget: float, period_s: float) -> None:
        if stride < 1 or max_stride < 1 or not 0.0 < budget <= 4.0 or not period_s > 0:
            raise InputError(
                "camera stride needs camera_stride >= 1, max_camera_stride >= 1, 0 < track_budget <= 4",
                field="camera_stride", got=(stride, max_stride, budget),
            )  # fmt: skip
        self.min, self.max, self.budget, self.period = int(stride), max(int(max_stride), int(stride)), budget, period_s
        self.stride = self.min
        self.last_t: float | None = None
        self.step_s: float | None = None  # running mean of the tracked steps' wall time, s
        self.skipped = 0
        self.hist: dict[int, int] = {}  # tracked frames per stride in force

    def take(self, t: float) -> bool:
        """Whether the camera frame at stream time ``t`` (s) is tracked (else it is skipped, counted)."""
        if self.last_t is not None and t - self.last_t < (self.stride - 0.5) * self.period:
            self.skipped += 1
            return False
        self.last_t = t
        self.hist[self.stride] = self.hist.get(self.stride, 0) + 1
        return True

    def done(self, wall_s: float) -> None:
        """A tracked step took ``wall_s`` s (wall time: what the other processes left it): set the stride."""
        self.step_s = wall_s if self.step_s is None else 0.7 * self.step_s + 0.3 * wall_s
        if self.max > self.min:
            need = int(np.ceil(self.step_s / (self.budget * self.period)))
            self.stride = int(np.clip(need, self.min, self.max))


@dataclass
class LiveReconstructConfig:
    """Options of :class:`ReconstructConsumer`: the live TSDF is coarser than the offline one
    (:class:`vtrack.fusion.tsdf.TSDFConfig`, 2 mm) to keep up with the camera. voxel_size m; block_count =
    initial TSDF hash-map capacity; depth_stride = keep every k-th depth pixel for segmentation."""

    voxel_size: float = 0.004
    block_count: int = 4000
    depth_stride: int = 4


class NullConsumer(Consumer):
    """Touches every field of every frame (a checksum) so the replay + transport cost is measured."""

    name = "null"

    def __init__(self, session: str | Path | None = None) -> None:
        self.checksum = 0

    def process(self, event: FrameEvent) -> None:
        for v in event.data.values():
            self.checksum += int(np.asarray(v).ravel()[::997].sum())

    def finish(self) -> dict[str, Any]:
        return {"checksum": self.checksum}


def _camera_raw(sf: Any, cam: Any, depth: np.ndarray, rgb: np.ndarray | None, strided: bool) -> dict:
    """The camera part of a live frame's raw input to :meth:`SessionFrames.build` (the layout of
    :meth:`SessionFrames.read`): ``depth`` at full resolution (``strided`` False; the colour term reads its tracks'
    depth there) or already subsampled by the depth stride; ``rgb`` (H, W, 3) for the colour term or None."""
    k = sf.depth_stride
    d = depth if strided else np.ascontiguousarray(depth[::k, ::k])
    raw: dict = {"cams": [(cam, d, None)]}
    if rgb is not None and cam.tracks is not None:
        raw["rgb"] = {cam.name: rgb}
        if not strided:
            raw["depth_full"] = {cam.name: depth}
    return raw


def _local(x: Any) -> np.ndarray:
    """An array sent to the helper: as it is, or a checked copy of a slot of the replay's shared ring (raises
    :class:`FrameOverwritten` if the slot was reused before it was read)."""
    return x if isinstance(x, np.ndarray) else x.read()


def _helper_process(
    session: str,
    modalities: tuple[str, ...],
    depth_stride: int,
    touch_stride: int,
    downsample: int,
    touch_conn: Any,
    frames_conn: Any,
    colour: bool = False,
    colour_opts: dict | None = None,
    stick_opts: dict | None = None,
) -> None:
    """Child process of the ``track`` consumer (:class:`_Helper`). ``touch_conn``: tactile images in, contacts
    (sensor frame) out; the newest contact per sensor is kept here. ``frames_conn``: a camera frame's depth (strided,
    or at full resolution / a slot of the replay's shared ring), its RGB image with ``colour`` (the feature tracks'
    state lives here, in the process that builds the frames), joints and time in, its
    :class:`~vtrack.tracking.frame.TrackingFrame` out (segmentation by the FK-posed hand with the newest contacts;
    with touch in another worker the request carries them; with the sticking-contact term on, ``stick_opts``: the
    tracker options that make :func:`~vtrack.tracking.stick.sticking_contacts_for` build the contact ids here, in
    frame order). When both wait they are served in turn. ``None`` on
    either connection ends the process; it answers with its CPU seconds since it was ready."""
    import time

    try:
        from vtrack.threads import limit_threads

        limit_threads(1)  # one stream of work per process: a BLAS pool would only spin beside the others
        from multiprocessing.connection import wait

        from vtrack.frames.session import SessionFrames

        sf = SessionFrames(
            session,
            modalities=modalities,
            depth_stride=depth_stride,
            touch_stride=touch_stride,
            touch_downsample=downsample,
            colour=colour,
            colour_opts=colour_opts,
        )
        cams = {f"camera/{c.name}": c for c in sf.cams}
        if sf.cams and "vision" in sf.modalities:
            # warm-up (lazy imports, ray-casting scenes, first-call costs; the colour tracks' too) on the first
            # camera frame, before the replay: not in the first frame's latency. Touch is left out (the tactile
            # pipeline takes its reference image from the first image it is given); the segmenter's and the
            # tracks' state is reset after.
            c = sf.cams[0]
            rgb = np.asarray(c.stream["rgb"][0]) if c.tracks is not None else None
            sf.build({"i": 0, "touch": [], **_camera_raw(sf, c, np.asarray(c.stream["depth"][0]), rgb, False)})
            sf.reset()
        from vtrack.tracking.stick import sticking_contacts_for

        sticker = sticking_contacts_for(stick_opts or {}, sf.modalities)  # after the warm-up: no state from it
    except Exception as e:  # reported by the parent as one line
        touch_conn.send(f"{type(e).__name__}: {e}")
        return
    touch_conn.send("ready")
    cpu0 = time.process_time()
    contacts: dict[str, Any] = {}
    last = touch_conn
    while True:
        ready = wait([frames_conn, touch_conn])
        # both waiting: take turns (a camera frame waits for at most one tactile image, ~2 ms, and a tactile
        # image for at most one camera frame: neither stream can starve the other)
        conn = ready[0] if len(ready) == 1 else (frames_conn if last is touch_conn else touch_conn)
        last = conn
        try:
            msg = conn.recv()
        except EOFError:
            return
        if msg is None:
            conn.send(("cpu", time.process_time() - cpu0))
            return
        c0 = time.thread_time()
        try:
            if msg[0] == "touch":  # ("touch", [(sensor, image or shared slot), ...]): a batch, oldest first
                out: list[Any] = [None] * len(msg[1])  # None: lost, counted as a dropped frame by the touch stage
                todo: list[tuple[int, str, np.ndarray]] = []
                for j, (sensor, image) in enumerate(msg[1]):
                    if not isinstance(image, np.ndarray):  # a slot of the replay's shared ring: read in place
                        try:
                            image = image.read()  # a copy (the pipeline may keep it as its reference), checked
                        except FrameOverwritten:
                            continue
                    todo.append((j, sensor, image))
                # the batch's images through their sensors' pipelines together (same values as one by one)
                got = sf.touch.contacts([(sensor, image) for _, sensor, image in todo])  # type: ignore[union-attr]
                for (j, sensor, _), c in zip(todo, got, strict=True):
                    contacts[sensor] = c
                    out[j] = (c.points, c.normals, c.penetration_mm, c.valid)
                conn.send((out, time.thread_time() - c0))
            else:  # ("frame", stream, t, q, touch, depth, rgb, strided): depth / rgb arrays or shared slots
                _, stream, t, q, touch, depth, rgb, strided = msg
                try:
                    depth = _local(depth)
                    rgb = None if rgb is None else _local(rgb)
                except FrameOverwritten as e:  # a dropped frame: the tracks never saw it
                    conn.send(f"FrameOverwritten: {e}")
                    continue
                raw = {
                    "t": t,
                    "q": q,
                    "touch": [] if q is None else (list(contacts.items()) if touch is None else touch),
                    **_camera_raw(sf, cams[stream], depth, rgb, strided),
                }
                fr = sf.build(raw)
                tf = fr.tracking_frame()
                if sticker is not None:
                    sticker.annotate(fr, tf)
                conn.send((tf, time.thread_time() - c0))
        except Exception as e:
            conn.send(f"{type(e).__name__}: {e}")


class _Helper:
    """The ``track`` consumer's child process (:func:`_helper_process`): the tactile pipeline and/or the
    frames layer (segmentation) off the tracker's process, so they run on the other core in parallel with the
    tracker step instead of sharing its GIL."""

    def __init__(self, owner: TrackConsumer) -> None:
        import multiprocessing as mp

        ctx = mp.get_context("spawn")  # no fork: the parent has threads (zarr's event loop)
        self.touch_conn, c_touch = ctx.Pipe()
        self.frames_conn, c_frames = ctx.Pipe()
        cfg = owner.config
        self.proc = ctx.Process(
            target=_helper_process,
            args=(
                str(owner.session),
                tuple(owner.sf.modalities),
                owner.sf.depth_stride,
                cfg.touch_stride,
                cfg.touch_downsample,
                c_touch,
                c_frames,
                owner.colour,
                owner.colour_opts,
                owner.tracker_opts if owner.sticker is not None else None,
            ),
            daemon=True,
            name="live-track-helper",
        )
        self.proc.start()
        if not self.touch_conn.poll(180):
            self.proc.kill()
            raise InputError("the live helper process did not start", path=owner.session)
        first = self.touch_conn.recv()
        if first != "ready":
            raise InputError(f"live helper process failed: {first}", path=owner.session)
        self.closed = False

    @staticmethod
    def call(conn: Any, msg: tuple) -> Any:
        conn.send(msg)
        got = conn.recv()
        if isinstance(got, str):
            if got.startswith("FrameOverwritten"):  # a shared slot reused before the helper read it: dropped
                raise FrameOverwritten(got)
            raise RuntimeError(f"live helper process: {got}")
        return got

    def close(self) -> float:
        """End the process (once); its CPU seconds over the run (0 when already closed)."""
        if self.closed:
            return 0.0
        self.closed = True
        cpu = 0.0
        try:
            self.touch_conn.send(None)
            if self.touch_conn.poll(5):
                got = self.touch_conn.recv()
                if isinstance(got, tuple) and got[0] == "cpu":
                    cpu = float(got[1])
        except (BrokenPipeError, EOFError, OSError):
            pass
        self.proc.join(5)
        if self.proc.is_alive():
            self.proc.kill()
        return cpu


class TouchConsumer(Consumer):
    """The tactile stage of :class:`TrackConsumer`: each tactile image through its sensor's calibrated
    tactile pipeline as it arrives; the newest contact per sensor (sensor frame) is what the next camera
    step uses.

    ``mode="thread"`` runs the pipeline in this worker thread (it shares the GIL with the tracker's
    thread); ``mode="process"`` in the consumer's child process (:class:`_Helper`; the worker thread only
    hands images over and waits with the GIL released, so tactile images and tracking use two cores). The
    child's CPU time per image is added to this worker's (``offload_cpu_s``)."""

    name = "track.touch"
    #: a burst (the other core taken by a tracker step and the reader) queues up to 4 images per sensor
    #: (67 ms at 60 Hz; the shared ring keeps >= 64 frames per stream) instead of losing them ...
    max_pending = 4
    #: ... and every pending image goes to the helper in one round trip (the 4 sensors of a time step)
    batch = True

    def __init__(self, owner: TrackConsumer, mode: str = "thread") -> None:
        self.owner = owner
        self.mode = mode
        self.offload_cpu_s = 0.0
        self.child_cpu_s = 0.0  # CPU s of the child process over the run (when this stage ended it)

    def wants(self, stream: str) -> bool:
        return stream in self.owner.touch_streams

    def process(self, ev: FrameEvent) -> None:
        if not self.process_batch([ev])[0]:
            raise FrameOverwritten(f"{ev.stream} frame {ev.index}")

    def process_batch(self, events: list[FrameEvent]) -> list[bool]:
        """The tactile images (oldest first) through their sensors' pipelines; the newest contact per sensor
        is kept for the camera step. An image whose shared slot was reused before it was read is lost (False)."""
        from vtrack.frames.touch import Contact

        names = [ev.stream.split("/", 1)[1] for ev in events]
        if self.mode != "process":
            todo = []
            for j, (s, ev) in enumerate(zip(names, events, strict=True)):
                try:
                    todo.append((j, s, ev.read("image")))  # own copy: the pipeline may keep it as its reference
                except FrameOverwritten:
                    pass
            got = self.owner.sf.touch.contacts([(s, image) for _, s, image in todo])  # type: ignore[union-attr]
            for (_, s, _), c in zip(todo, got, strict=True):
                self.owner.images[s] = c
                self.owner.touch_steps += 1
            done = {j for j, _, _ in todo}
            return [j in done for j in range(len(events))]
        # a frame in the replay's shared ring goes by reference (the helper maps the ring), else pickled
        msg = [(s, ev.shared["image"] if ev.shared and "image" in ev.shared else ev.data["image"]) for s, ev in
               zip(names, events, strict=True)]  # fmt: skip
        got, cpu = _Helper.call(self.owner.touch_helper.touch_conn, ("touch", msg))  # type: ignore[union-attr]
        self.offload_cpu_s = cpu
        for s, g in zip(names, got, strict=True):
            if g is not None:
                # one dict item assignment: atomic for the camera step reading it
                self.owner.images[s] = Contact(*g)
                self.owner.touch_steps += 1
        return [g is not None for g in got]

    def finish(self) -> dict[str, Any]:
        if self.owner.touch_helper is not None:
            self.child_cpu_s = self.owner.touch_helper.close()
        return {"mode": self.mode}


class FramesConsumer(Consumer):
    """The frames stage of :class:`TrackConsumer` (``frames_worker="process"``): each camera frame is
    segmented and turned into a tracking frame in the consumer's child process, then handed to the tracker's
    mailbox as stream ``frames/<camera stream>`` (:data:`vtrack.live.pipeline.DERIVED_PREFIX`; its emission
    time is the camera frame's, so latency is from the camera). Segmenting frame k+1 while the tracker steps
    on frame k takes segmentation off the camera path's critical step. With touch in this process
    (``touch_worker`` ``thread``/``off``) the newest contacts / tactile images go with the request."""

    name = "track.frames"

    def __init__(self, owner: TrackConsumer) -> None:
        self.owner = owner
        self.offload_cpu_s = 0.0
        self.child_cpu_s = 0.0
        self.q: np.ndarray | None = None

    def wants(self, stream: str) -> bool:
        o = self.owner
        if stream in o.touch_streams:
            return o._touch is None  # touch_worker="off": the newest raw image goes with the frame
        return stream in o.cams or (stream == "joints" and o.sf.kin is not None)

    def process(self, ev: FrameEvent) -> None:
        o = self.owner
        if ev.stream == "joints":
            self.q = o._joints(ev)
            return
        if ev.stream in o.touch_streams:
            o.images[ev.stream.split("/", 1)[1]] = ev.read("image")  # kept until the next camera frame
            return
        if not o.stride.take(ev.t):  # not tracked: not segmented either
            return
        # the shared helper keeps the contacts it computed; else the newest ones (or raw images) go along
        touch = None if o.frames_helper is o.touch_helper else list(o.images.items())
        sh = ev.shared or {}
        colour = ev.stream in o.colour_cams and "rgb" in ev.data
        rgb = (sh["rgb"] if "rgb" in sh else ev.data["rgb"]) if colour else None
        if "depth" in sh:  # in the replay's shared ring: the helper reads (and strides) it in place
            depth, strided = sh["depth"], False
        elif colour:  # the colour tracks read their depth at full resolution
            depth, strided = ev.data["depth"], False
        else:
            k = o.sf.depth_stride
            depth, strided = ev.read("depth", lambda d: np.ascontiguousarray(d[::k, ::k])), True
        msg = ("frame", ev.stream, ev.t, self.q, touch, depth, rgb, strided)
        fr, cpu = _Helper.call(o.frames_helper.frames_conn, msg)  # type: ignore[union-attr]
        self.offload_cpu_s = cpu
        if self.forward is not None:
            from vtrack.live.pipeline import DERIVED_PREFIX

            self.forward(FrameEvent(DERIVED_PREFIX + ev.stream, ev.t, ev.index, {"frame": fr}, ev.wall))

    def finish(self) -> dict[str, Any]:
        if self.owner.frames_helper is not None:
            self.child_cpu_s = self.owner.frames_helper.close()
        return {"mode": self.owner.config.frames_worker}


class TrackConsumer(Consumer):
    """In-hand tracking on the live stream through the frames layer (no ground truth).

    Joint states and tactile images update the newest state; each camera frame is segmented (hand removed
    by forward kinematics), the newest tactile images go through the calibrated tactile pipeline, and the
    tracker takes one step. Known shape when ``mesh`` is given (initial pose ``init_pose``, else global
    registration on the first frame), else SLAM (object frame at the first frame's centroid).
    """

    name = "track"

    def __init__(
        self,
        session: str | Path,
        mesh: str | Path | None = None,
        init_pose: np.ndarray | None = None,
        *,
        config: LiveTrackConfig | None = None,
        depth_stride: int | None = None,
        **tracker_opts: Any,
    ) -> None:
        from vtrack.config import build_config
        from vtrack.frames.session import SessionFrames

        cfg_opts = {k: tracker_opts.pop(k) for k in list(tracker_opts) if k in LiveTrackConfig.__dataclass_fields__}
        if depth_stride is not None:
            cfg_opts["depth_stride"] = depth_stride
        self.config = build_config(LiveTrackConfig, cfg_opts, "live tracking", base=config)
        depth_stride = self.config.depth_stride
        self.session = Path(session)
        self.mesh = None if mesh is None else Path(mesh)
        # the colour term's feature tracks only when the tracker uses them (as offline: `track_session`)
        self.colour_opts = tracker_opts.pop("colour_opts", None)
        self.colour = self.config.colour and colour_term_on(
            "known_shape" if self.mesh is not None else "slam", tracker_opts
        )
        col = {"colour": self.colour, "colour_opts": self.colour_opts}
        try:
            self.sf = SessionFrames(
                self.session,
                modalities=("vision", "touch"),
                depth_stride=depth_stride,
                touch_stride=self.config.touch_stride,
                touch_downsample=self.config.touch_downsample,
                **col,
            )
        except InputError:  # e.g. a sensor without calibration: vision only, said in the result
            self.sf = SessionFrames(self.session, modalities=("vision",), depth_stride=depth_stride, **col)
        self.init_pose = init_pose
        self.tracker_opts = tracker_opts
        from vtrack.tracking.stick import stick_term_on, sticking_contacts_for

        # the sticking-contact term's ids (``--contacts stick``), as offline; with a frames worker its twin in the
        # child builds them (this one stays unused)
        self.sticker = sticking_contacts_for(tracker_opts, self.sf.modalities) if self.mesh is None else None
        if stick_term_on(tracker_opts) and self.sticker is None:
            raise InputError(
                "the sticking-contact term needs touch and SLAM",
                path=self.session,
                field="contacts",
                expected="calibrated tactile sensors and no mesh",
                got=f"modalities {','.join(self.sf.modalities)}" + (", a mesh" if self.mesh is not None else ""),
            )
        self.tracker: Any = None
        self.reloc: Any = None  # known shape: run.Relocalisation once the tracker starts
        self.cams = {f"camera/{c.name}": c for c in self.sf.cams}
        # cameras whose RGB the colour term reads (those with an ``rgb`` field); with a frames worker their tracks
        # are the helper process's (this process's stay unused)
        self.colour_cams = {k for k, c in self.cams.items() if c.tracks is not None}
        self.touch_streams = [f"tactile/{s}" for s in (self.sf.touch.sensors if self.sf.touch else [])]
        self.q: np.ndarray | None = None
        self.images: dict[str, Any] = {}  # newest tactile image (or its Contact, with the touch worker) per sensor
        self.touch_steps = 0
        self.poses: list[tuple[float, np.ndarray]] = []
        mode = self.config.touch_worker
        if mode not in ("process", "thread", "off"):
            raise InputError("unknown touch worker", field="touch_worker", expected="process|thread|off", got=mode)
        fmode = self.config.frames_worker
        if fmode not in ("process", "shared", "inline"):
            raise InputError(
                "unknown frames worker", field="frames_worker", expected="process|shared|inline", got=fmode
            )
        c = self.config
        t = np.asarray(self.sf.times, dtype=np.float64)
        period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        if not (np.isfinite(period) and period > 0):  # a stream still being recorded: assume 30 Hz
            period = 1.0 / 30.0
        self.stride = CameraStride(c.camera_stride, c.max_camera_stride, c.track_budget, period)
        self._touch = TouchConsumer(self, mode) if (mode != "off" and self.touch_streams) else None
        self._frames = FramesConsumer(self) if fmode != "inline" else None
        self.touch_helper: _Helper | None = None
        self.frames_helper: _Helper | None = None
        if self._touch is not None and mode == "process":
            self.touch_helper = _Helper(self)
        if self._frames is not None:
            shared = fmode == "shared" and self.touch_helper is not None
            self.frames_helper = self.touch_helper if shared else _Helper(self)
        from vtrack.tracking.run import warm_up

        # imports (open3d, scipy, ...) before the replay starts, not in the first frame's latency
        warm_up("known_shape" if self.mesh is not None else "slam", write=False)
        import scipy.ndimage  # noqa: F401  (the SLAM grid update)

    def parts(self) -> list[Consumer]:
        return [p for p in (self._touch, self._frames) if p is not None] + [self]

    def streams(self) -> list[str]:
        s = list(self.cams) + self.touch_streams
        if self.sf.kin is not None:
            s.append("joints")
        return s

    def fields(self) -> dict[str, list[str]]:
        """The fields this consumer reads per stream (a camera's colour image only for the colour term)."""
        out = {c: ["depth", "rgb"] if c in self.colour_cams else ["depth"] for c in self.cams}
        out |= {s: ["image"] for s in self.touch_streams}
        if self.sf.kin is not None:
            out["joints"] = ["q"]
        return out

    def wants(self, stream: str) -> bool:
        if self._frames is not None:  # frames come from the frames stage, built
            from vtrack.live.pipeline import DERIVED_PREFIX

            return stream.startswith(DERIVED_PREFIX) and stream[len(DERIVED_PREFIX) :] in self.cams
        if stream in self.touch_streams:
            return self._touch is None
        return stream in self.cams or (stream == "joints" and self.sf.kin is not None)

    def _joints(self, ev: FrameEvent) -> np.ndarray:
        q = np.asarray(ev.data["q"], dtype=np.float64)[None]
        return self.sf.kin.reorder(q, self.sf.reader["joints"].attrs.get("joint_names"))[0]

    def _start(self, frame: Any) -> None:
        from vtrack.tracking.run import (
            Relocalisation,
            build_tracker,
            centroid_frame,
            known_shape_touch_defaults,
            register_known_shape,
        )

        if self.mesh is not None:
            symmetric = bool(self.sf.scene.object.symmetric)
            T0 = self.init_pose
            if T0 is None:
                try:
                    T0, _ = register_known_shape(self.mesh, [frame], symmetric)
                except InputError:  # nothing to register on yet: try the next frame
                    return
            # the offline contact settings for the same modalities (`track_session`)
            opts = known_shape_touch_defaults(dict(self.tracker_opts), self.sf.modalities)
            self.tracker = build_tracker("known_shape", self.mesh, T0, **opts)
            self.reloc = Relocalisation(self.tracker, self.mesh, symmetric)  # as offline: recover after a loss
        else:
            T0 = centroid_frame(frame)
            if T0 is not None:
                self.tracker = build_tracker("slam", None, T0, **self.tracker_opts)

    def process(self, ev: FrameEvent) -> None:
        if "frame" in ev.data:  # built by the frames stage
            t0 = time.perf_counter()
            self._step(ev, ev.data["frame"])
            self.stride.done(time.perf_counter() - t0)
            return
        if ev.stream == "joints":
            self.q = self._joints(ev)
            return
        if ev.stream in self.touch_streams:
            self.images[ev.stream.split("/", 1)[1]] = ev.read("image")  # kept until the next camera frame
            return
        if not self.stride.take(ev.t):
            return
        t0 = time.perf_counter()
        c = self.cams[ev.stream]
        if ev.stream in self.colour_cams and "rgb" in ev.data:  # the colour term: RGB and full-resolution depth
            cam = _camera_raw(self.sf, c, ev.read("depth"), ev.read("rgb"), False)
        else:
            k = self.sf.depth_stride
            cam = _camera_raw(self.sf, c, ev.read("depth", lambda d: np.ascontiguousarray(d[::k, ::k])), None, True)
        raw = {"t": ev.t, "q": self.q, "touch": list(self.images.items()) if self.q is not None else [], **cam}
        fr = self.sf.build(raw)
        tf = fr.tracking_frame()
        if self.sticker is not None:  # inline frames: the contact ids are built here, in frame order
            self.sticker.annotate(fr, tf)
        self._step(ev, tf)
        self.stride.done(time.perf_counter() - t0)

    def _step(self, ev: FrameEvent, frame: Any) -> None:
        """One tracker step on a camera frame's tracking frame (the first frames start the tracker)."""
        if self.tracker is None:
            self._start(frame)
            if self.tracker is None:
                return
        T = self.tracker.step(frame)
        if self.reloc is not None:
            info = getattr(self.tracker, "last_info", None)
            T, _ = self.reloc.update(frame, T, info.status if info is not None else "ok")
        self.poses.append((ev.t, np.asarray(T)))

    def finish(self) -> dict[str, Any]:
        for h in (self.touch_helper, self.frames_helper):  # ended by a stage's finish; here too if not run
            if h is not None:
                h.close()
        out: dict[str, Any] = {
            "steps": len(self.poses),
            "touch_steps": self.touch_steps,
            "touch_worker": self._touch.mode if self._touch is not None else "off",
            "frames_worker": "process" if self._frames is not None else "inline",
            # camera frames not tracked by the stride policy, and tracked frames per stride in force
            "camera_skipped": self.stride.skipped,
            "stride_hist": {str(k): v for k, v in sorted(self.stride.hist.items())},
            "modalities": list(self.sf.modalities),
            "mode": "known_shape" if self.mesh is not None else "slam",
            "colour": sorted(self.colour_cams),  # cameras whose feature tracks fed the colour term
            "sticking_contacts": self.sticker is not None,  # the sticking-contact term had contact ids
        }
        if self.reloc is not None:
            out["reloc_attempts"], out["reloc_successes"] = self.reloc.attempts, self.reloc.successes
        if len(self.poses) > 1:
            from vtrack.eval.session_gt import SessionGroundTruth, score_trajectory

            gt = SessionGroundTruth.find(None, self.session)  # scoring only, after the run
            if gt is None:
                return out
            t = np.array([p[0] for p in self.poses])
            T = np.stack([p[1] for p in self.poses])
            m, _ = score_trajectory(gt, t, T, mesh=self.mesh)
            out["motion_err_mm"] = round(float(m["motion_err_mm"]), 3)
            out["motion_add_s_mm"] = round(float(m["motion_add_s_mm"]), 3)
            if "add_s_mm" in m:
                out["add_s_mm"] = round(float(m["add_s_mm"]), 3)
        return out


class ReconstructConsumer(Consumer):
    """TSDF reconstruction on the live stream: each camera frame's depth, segmented by the frames layer
    (no ground truth), is integrated in the object frame given by ``poses`` (a ``poses.csv`` of
    ``T_world_object``, e.g. from ``vtrack track``); without poses the object is taken as static in the
    world frame."""

    name = "reconstruct"

    def __init__(
        self,
        session: str | Path,
        poses: str | Path | None = None,
        *,
        config: LiveReconstructConfig | None = None,
        **opts: Any,
    ) -> None:
        from vtrack import registry
        from vtrack.config import build_config
        from vtrack.frames.session import SessionFrames

        self.config = c = build_config(LiveReconstructConfig, opts, "live reconstruction", base=config)
        self.sf = SessionFrames(session, modalities=("vision",), depth_stride=c.depth_stride)
        self.tsdf = registry.load("reconstruction.tsdf")(voxel_size=c.voxel_size, block_count=c.block_count)
        self.cams = {f"camera/{c.name}": c for c in self.sf.cams}
        if not self.cams:
            raise InputError("live reconstruction needs a camera stream", path=self.sf.path)
        self.poses = None
        if poses is not None:
            from vtrack.io.poses import read_poses_csv

            self.poses = read_poses_csv(poses)
        self.q: np.ndarray | None = None
        self.integrated = 0

    def streams(self) -> list[str]:
        return list(self.cams) + (["joints"] if self.sf.kin is not None else [])

    def fields(self) -> dict[str, list[str]]:
        return {c: ["depth"] for c in self.cams} | ({"joints": ["q"]} if self.sf.kin is not None else {})

    def wants(self, stream: str) -> bool:
        return stream in self.cams or (stream == "joints" and self.sf.kin is not None)

    def process(self, ev: FrameEvent) -> None:
        from vtrack.frames.session import upsample_mask
        from vtrack.geometry import se3

        if ev.stream == "joints":
            q = np.asarray(ev.data["q"], dtype=np.float64)[None]
            self.q = self.sf.kin.reorder(q, self.sf.reader["joints"].attrs.get("joint_names"))[0]
            return
        c = self.cams[ev.stream]
        k = self.sf.depth_stride
        depth = ev.read("depth")
        fr = self.sf.build({"t": ev.t, "q": self.q, "cams": [(c, depth[::k, ::k], None)], "touch": []})
        mask = upsample_mask(fr.vision_mask[c.name], depth.shape)
        d = np.where(mask, depth.astype(np.float32) * c.depth_scale, 0.0).astype(np.float32)
        T_wo = np.eye(4) if self.poses is None else self.poses.at(np.array([ev.t]))[0]
        self.integrated += int(self.tsdf.integrate_depth(d, c.cam.K, se3.invert(c.T_wc) @ T_wo))

    def finish(self) -> dict[str, Any]:
        V, F = self.tsdf.extract_mesh()
        return {"integrated": self.integrated, "mesh_vertices": int(len(V)), "mesh_faces": int(len(F))}


def make_consumer(kind: str, session: str | Path, **opts: Any) -> Consumer:
    """The live consumer ``kind`` (``track`` | ``reconstruct`` | ``null``, registry key ``live.<kind>``) on
    ``session`` with its options (see the consumer's config)."""
    from vtrack import registry

    kinds = [k.split(".", 1)[1] for k in registry.COMPONENTS if k.startswith("live.")]
    if kind not in kinds:
        raise InputError("unknown live consumer", field="--consumer", expected="|".join(kinds), got=kind)
    return registry.load(f"live.{kind}")(session, **opts)


def replay_fields(consumers: list[Consumer]) -> dict[str, list[str]] | None:
    """Per stream, the union of the fields the consumers read (None: a consumer reads every field)."""
    out: dict[str, set[str]] = {}
    for c in consumers:
        if not hasattr(c, "fields"):
            return None
        for k, fs in c.fields().items():
            out.setdefault(k, set()).update(fs)
    return {k: sorted(v) for k, v in out.items()}


def replay_streams(session: str | Path, consumers: list[Consumer]) -> list[str]:
    """Streams a replay must emit for these consumers: each consumer's ``streams()``, plus the
    default live streams (cameras, tactile images, joints) when a consumer takes everything."""
    from vtrack.io.session import open_session

    r = open_session(session)
    out: set[str] = set()
    for c in consumers:
        if hasattr(c, "streams"):
            out |= set(c.streams())
        else:
            out |= {k for k in r.streams if k.startswith(("camera/", "tactile/")) or k == "joints"}
    return sorted(k for k in out if k in r and r[k].n)
