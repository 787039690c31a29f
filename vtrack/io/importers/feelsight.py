"""Import a FeelSight (NeuralFeels) log folder into a vtrack session.

Layout of one log (``feelsight/<object>/<NN>/``)::

    allegro/<finger>/image/<i>.jpg     # DIGIT images (index, middle, ring, thumb)
    allegro/<finger>/depth/<i>.jpg     # simulation only: ground-truth tactile depth (8-bit)
    allegro/<finger>/mask/<i>.jpg      # simulation only: ground-truth contact mask
    realsense/<camera>/image/<i>.jpg   # RGB images per camera (front-left, ...)
    realsense/<camera>/seg/<i>.jpg     # simulation only: object segmentation
    realsense/<camera>/depth.npz       # depth images, key "depth" (N, H, W), metres (float) or uint16
    data.pkl                           # pickle: see below

``data.pkl`` keys read (as NeuralFeels' loaders read them):

- ``time`` (N,) s; ``allegro.joint_state`` (N, 16) rad in Allegro order (index, middle, ring,
  thumb; joint_0.0 ... joint_15.0); ``allegro.base_pose`` 4x4 ``T_world_base`` (or 7-vector
  xyz + quaternion xyzw); ``object.pose`` (N, 4, 4) ``T_world_object``;
- camera calibration from ``realsense.<camera>`` (or ``cam_info.<camera>``): ``intrinsics``
  (3x3 K or dict fx/fy/cx/cy), ``pose``/``extrinsics`` (4x4 ``T_world_camera``), optional
  ``depth_scale`` (m per unit for integer depth);
- ``digit_info`` (sensor info) is copied into the session manifest.

Streams written: ``camera/<camera>`` (rgb, depth uint16 mm, mask when ``seg`` exists),
``tactile/digit_<finger>`` (image, BGR), ``joints`` (q), ``gt/object_pose``, and
``gt/tactile_raw/digit_<finger>`` (``depth_u8``, ``contact``) when the simulation ground truth
exists (the 8-bit depth is kept raw: its metric scale is not stated by the dataset).
"""

from __future__ import annotations

import pickle
import re
import time
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.io.images import read_image
from vtrack.io.importers.report import ImportReport
from vtrack.io.streams import encode_depth

FINGERS = ("index", "middle", "ring", "thumb")
ALLEGRO_JOINTS = [f"joint_{i}.0" for i in range(16)]
_IMG_EXT = (".jpg", ".jpeg", ".png")


def _numbered_images(folder: Path) -> list[Path]:
    """Image files of a folder sorted by the integer in their name (``0.jpg, 1.jpg, ..., 10.jpg``)."""
    files = [p for p in folder.iterdir() if p.suffix.lower() in _IMG_EXT]

    def key(p: Path) -> tuple[int, str]:
        m = re.findall(r"\d+", p.stem)
        return (int(m[-1]) if m else -1, p.name)

    return sorted(files, key=key)


#: The only globals a ``data.pkl`` may reference unless the user trusts it: numpy arrays, dtypes and
#: scalars, and builtin containers. Any other global (``os.system``, ``subprocess.Popen``, ...) is
#: how a pickle runs code on load, so it is refused.
_SAFE_GLOBALS = {
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "scalar"),
    ("numpy.core.multiarray", "scalar"),
    ("numpy._core.numeric", "_frombuffer"),
    ("numpy.core.numeric", "_frombuffer"),
    ("_codecs", "encode"),
    ("collections", "OrderedDict"),
    ("builtins", "set"),
    ("builtins", "frozenset"),
    ("builtins", "complex"),
    ("builtins", "slice"),
    ("builtins", "range"),
    ("builtins", "bytearray"),
    ("__builtin__", "set"),
    ("__builtin__", "frozenset"),
    ("__builtin__", "complex"),
}


class UnsafePickleError(InputError):
    """A pickle references a global outside the data-only allow-list (it could run code on load)."""


def _restricted_unpickler(f: Any) -> pickle.Unpickler:
    import importlib

    class _Restricted(pickle.Unpickler):
        def find_class(self, module: str, name: str) -> Any:
            if (module, name) not in _SAFE_GLOBALS:
                raise UnsafePickleError(
                    f"refusing to unpickle '{module}.{name}': data.pkl may only hold numpy arrays, "
                    "numbers, strings and builtin containers (pass --trust-pickle to load a file you trust)"
                )
            # importlib (not super().find_class) so the Python-2 '__builtin__' alias resolves too.
            return getattr(importlib.import_module("builtins" if module == "__builtin__" else module), name)

    return _Restricted(f)


def load_data_pkl(path: Path, *, trust: bool = False) -> dict:
    """Read ``data.pkl`` safely.

    By default a restricted unpickler is used: only numpy arrays/dtypes/scalars and builtin
    containers and scalars may appear; anything else (the way a pickle executes code on load) is
    refused with an :class:`InputError`. ``trust=True`` uses plain pickle (then dill, if installed)
    and warns: it runs whatever code the file holds.

    Raises:
        InputError: missing, truncated or corrupt file, a disallowed global, or not a dict.
    """
    if not path.exists():
        raise InputError("FeelSight log has no data.pkl", path=path)
    if trust:
        import warnings

        warnings.warn(
            f"{path}: loading with plain pickle (--trust-pickle): this runs any code the file holds", stacklevel=2
        )
    try:
        with open(path, "rb") as f:
            data = pickle.load(f) if trust else _restricted_unpickler(f).load()
    except UnsafePickleError as e:
        raise UnsafePickleError(str(e), path=path) from None
    except Exception as e:  # truncated / corrupt pickles raise many types
        if not trust:
            raise InputError(f"cannot read pickle ({type(e).__name__}: {e})", path=path) from None
        try:
            import dill  # type: ignore[import-not-found]

            with open(path, "rb") as f:
                data = dill.load(f)
        except Exception:
            raise InputError(f"cannot read pickle ({type(e).__name__}: {e})", path=path) from None
    if not isinstance(data, dict):
        raise InputError("data.pkl does not hold a dict", path=path, got=type(data).__name__)
    return data


def _get(d: Any, *keys: str) -> Any:
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _pose_matrix(v: Any, what: str, path: Path) -> np.ndarray:
    from vtrack.geometry import se3

    a = np.asarray(v, dtype=np.float64)
    if a.shape == (4, 4):
        return a
    if a.shape == (7,):
        return se3.make_transform(se3.quat_to_matrix(a[3:]), a[:3])
    raise InputError("pose must be 4x4 or xyz+quat_xyzw (7,)", path=path, field=what, got=a.shape)


def _intrinsics(v: Any, path: Path, cam: str) -> np.ndarray:
    if isinstance(v, dict):
        try:
            return np.array([[v["fx"], 0, v["cx"]], [0, v["fy"], v["cy"]], [0, 0, 1]], dtype=np.float64)
        except KeyError as e:
            raise InputError(f"intrinsics dict lacks {e}", path=path, field=f"realsense.{cam}.intrinsics") from None
    K = np.asarray(v, dtype=np.float64)
    if K.shape == (4,):  # fx, fy, cx, cy
        return np.array([[K[0], 0, K[2]], [0, K[1], K[3]], [0, 0, 1]])
    if K.shape != (3, 3):
        raise InputError(
            "intrinsics must be 3x3, (fx, fy, cx, cy) or a dict",
            path=path,
            field=f"realsense.{cam}.intrinsics",
            got=K.shape,
        )
    return K


class DepthFrames:
    """Frames of ``depth.npz`` (key ``depth``, (N, H, W)), decompressed on demand in order.

    A compressed ``.npz`` cannot be memory-mapped; loading it whole costs N*H*W*4 bytes (1.2 GB for
    1000 VGA frames). This reads the ``.npy`` member's header and then streams one frame at a time
    through the zip decompressor (sequential access; a backwards seek restarts the stream).
    """

    def __init__(self, path: Path) -> None:
        import zipfile

        self.path = path
        try:
            self._zip = zipfile.ZipFile(path)
            names = self._zip.namelist()
        except Exception as e:
            raise InputError(f"cannot read depth archive ({type(e).__name__}: {e})", path=path) from None
        member = "depth.npy" if "depth.npy" in names else (names[0] if len(names) == 1 else None)
        if member is None:
            raise InputError("depth.npz has no 'depth' array", path=path, got=names)
        self.member = member
        self._open()
        if len(self.shape) != 3:
            raise InputError("depth array must be (N, H, W)", path=path, field="depth", got=self.shape)
        self.frame_bytes = int(np.prod(self.shape[1:])) * self.dtype.itemsize

    def _open(self) -> None:
        from numpy.lib import format as npf

        try:
            self._f = self._zip.open(self.member)
            version = npf.read_magic(self._f)
            if version == (1, 0):
                shape, fortran, dtype = npf.read_array_header_1_0(self._f)
            elif version == (2, 0):
                shape, fortran, dtype = npf.read_array_header_2_0(self._f)
            else:  # (3, 0): utf-8 header, no public reader
                from numpy.lib import _format_impl

                shape, fortran, dtype = _format_impl._read_array_header(self._f, version)
        except Exception as e:
            raise InputError(f"corrupt depth array ({type(e).__name__}: {e})", path=self.path) from None
        if fortran or dtype.hasobject:
            raise InputError("depth array must be a C-ordered numeric array", path=self.path, field="depth")
        self.shape, self.dtype = tuple(shape), np.dtype(dtype)
        self._next = 0

    def __len__(self) -> int:
        return int(self.shape[0])

    def __getitem__(self, i: int) -> np.ndarray:
        if not 0 <= i < len(self):
            raise IndexError(i)
        try:
            if i < self._next:
                self._f.close()
                self._open()
            while self._next < i:  # skip frames
                self._f.read(self.frame_bytes)
                self._next += 1
            buf = self._f.read(self.frame_bytes)
        except Exception as e:
            raise InputError(
                f"truncated or corrupt depth archive at frame {i} ({type(e).__name__})", path=self.path
            ) from None
        if len(buf) != self.frame_bytes:
            raise InputError(f"depth archive ends at frame {i}", path=self.path, expected=f"{len(self)} frames")
        self._next = i + 1
        return np.frombuffer(buf, self.dtype).reshape(self.shape[1:])


def import_feelsight(
    src: str | Path,
    out: str | Path,
    *,
    overwrite: bool = False,
    flush_every: int = 256,
    max_frames: int | None = None,
    object_mesh: str | Path | None = None,
    hand_urdf: str | None = "${shared}/data/robots/allegro_digit/allegro_digit_left.urdf",
    rate_hz: float | None = None,
    trust_pickle: bool = False,
) -> ImportReport:
    """Convert one FeelSight log folder to a session at ``out``.

    Args:
        src: the log folder (holding ``data.pkl``, ``allegro/``, ``realsense/``).
        out: session directory to write.
        overwrite: replace an existing session.
        flush_every: frames per commit (larger = faster import).
        max_frames: import only the first frames (for quick looks).
        object_mesh: object mesh to reference in the scene (the dataset does not ship it per log).
        hand_urdf: URDF of the DIGIT-Allegro hand for the scene's ``hand`` entry (None: no hand).
        rate_hz: nominal rate; default from ``time``.
        trust_pickle: load ``data.pkl`` with plain pickle (runs code in the file; default: data only).

    Raises:
        InputError: missing/corrupt ``data.pkl``, images or depth archive (the message names the file),
            inconsistent frame counts.
    """
    from vtrack.io.importers.scene_build import camera_entry, finalize_scene, tactile_entry, write_scene_yaml
    from vtrack.io.session import FieldSpec, SessionWriter, StreamSpec
    from vtrack.io.streams import joints_stream, pose_stream

    t_start = time.perf_counter()
    src = Path(src)
    if not src.is_dir():
        raise InputError("FeelSight log folder does not exist", path=src)
    pkl = src / "data.pkl"
    data = load_data_pkl(pkl, trust=trust_pickle)
    report = ImportReport(source=src, session=Path(out))

    t = _get(data, "time")
    if t is None:
        raise InputError("data.pkl has no 'time'", path=pkl, field="time")
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(t)):
        raise InputError("non-finite timestamps", path=pkl, field="time")
    n = len(t)
    q = _get(data, "allegro", "joint_state")
    if q is not None:
        q = np.asarray(q, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != 16:
            raise InputError("joint_state must be (N, 16)", path=pkl, field="allegro.joint_state", got=q.shape)
        if len(q) != n:
            report.note(f"allegro.joint_state has {len(q)} rows for {n} timestamps: using the common prefix")
            n = min(n, len(q))
    obj = _get(data, "object", "pose")
    if obj is not None:
        obj = np.asarray(obj, dtype=np.float64)
        if obj.ndim != 3 or obj.shape[1:] != (4, 4):
            raise InputError("object pose must be (N, 4, 4)", path=pkl, field="object.pose", got=obj.shape)
        n = min(n, len(obj)) if len(obj) >= 1 else n
    # Time must be strictly increasing; keep the frames where it is (report the others).
    keep = np.ones(n, dtype=bool)
    last = -np.inf
    for i in range(n):
        if t[i] <= last:
            keep[i] = False
        else:
            last = t[i]
    if (~keep).sum():
        report.skip("frames with non-increasing time", int((~keep).sum()))
    if max_frames is not None:
        idx_all = np.nonzero(keep)[0][:max_frames]
        keep[:] = False
        keep[idx_all] = True
    frames = np.nonzero(keep)[0]
    if len(frames) == 0:
        raise InputError("no frames to import", path=pkl, field="time")
    dt = np.diff(t[frames])
    rate = rate_hz or (float(1.0 / np.median(dt)) if len(dt) else 30.0)

    # --- discover sensors -------------------------------------------------------------------
    fingers = {}
    allegro_dir = src / "allegro"
    if allegro_dir.is_dir():
        for fd in sorted(p for p in allegro_dir.iterdir() if p.is_dir()):
            imgs = _numbered_images(fd / "image") if (fd / "image").is_dir() else []
            if not imgs:
                report.skip(f"allegro/{fd.name}: no image/ folder")
                continue
            fingers[fd.name] = {
                "image": imgs,
                "depth": _numbered_images(fd / "depth") if (fd / "depth").is_dir() else [],
                "mask": _numbered_images(fd / "mask") if (fd / "mask").is_dir() else [],
            }
    else:
        report.note("no allegro/ folder: no tactile streams")
    cams = {}
    rs_dir = src / "realsense"
    if rs_dir.is_dir():
        for cd in sorted(p for p in rs_dir.iterdir() if p.is_dir()):
            imgs = _numbered_images(cd / "image") if (cd / "image").is_dir() else []
            if not imgs or not (cd / "depth.npz").exists():
                report.skip(f"realsense/{cd.name}: needs image/ and depth.npz")
                continue
            cams[cd.name] = {
                "image": imgs,
                "seg": _numbered_images(cd / "seg") if (cd / "seg").is_dir() else [],
                "depth_path": cd / "depth.npz",
            }

    # --- per-sensor frame counts --------------------------------------------------------------
    def check_count(what: str, count: int) -> None:
        if count < frames[-1] + 1:
            raise InputError(
                f"{what} has {count} frames but data.pkl has {len(t)} timestamps (need at least {frames[-1] + 1})",
                path=src / what,
            )

    for fname, f in fingers.items():
        check_count(f"allegro/{fname}/image", len(f["image"]))
        for kind in ("depth", "mask"):
            if f[kind] and len(f[kind]) < frames[-1] + 1:
                report.skip(f"allegro/{fname}/{kind}: too few frames ({len(f[kind])})")
                f[kind] = []
    # --- scene ---------------------------------------------------------------------------------
    scene: dict[str, Any] = {
        "name": f"feelsight_{src.parent.name}_{src.name}",
        "description": f"imported from FeelSight log {src}",
        "object": {"name": src.parent.name or "object"},
    }
    if object_mesh:
        scene["object"]["mesh"] = str(object_mesh)
    cam_specs = {}
    for cname, c in cams.items():
        info = _get(data, "realsense", cname) or _get(data, "cam_info", cname) or {}
        depth = DepthFrames(c["depth_path"])
        check_count(f"realsense/{cname}/image", len(c["image"]))
        if len(depth) < frames[-1] + 1:
            raise InputError(f"depth archive has {len(depth)} frames, need {frames[-1] + 1}", path=c["depth_path"])
        first = read_image(c["image"][frames[0]], "color")
        h, w = first.shape[:2]
        if tuple(depth.shape[1:]) != (h, w):
            raise InputError(
                "depth frames are not the size of the colour images",
                path=c["depth_path"],
                expected=f"(N, {h}, {w})",
                got=depth.shape,
            )
        K_raw = info.get("intrinsics", info.get("K")) if isinstance(info, dict) else None
        if K_raw is None:
            K = np.array([[float(w), 0, (w - 1) / 2], [0, float(w), (h - 1) / 2], [0, 0, 1]])
            report.note(f"realsense/{cname}: no intrinsics in data.pkl, assumed fx = fy = width px")
        else:
            K = _intrinsics(K_raw, pkl, cname)
        T_raw = None
        if isinstance(info, dict):
            T_raw = info.get("pose", info.get("extrinsics", info.get("T_world_camera")))
        T = _pose_matrix(T_raw, f"realsense.{cname}.pose", pkl) if T_raw is not None else None
        if T is None:
            report.note(f"realsense/{cname}: no extrinsics in data.pkl, camera placed at the world origin")
        scale = float(info.get("depth_scale", 0.001)) if isinstance(info, dict) else 0.001
        # Store as uint16 mm for float (metre) depth; integer depth keeps its own scale.
        store_scale = 0.001 if depth.dtype.kind == "f" else scale
        cam_specs[cname] = (depth, store_scale, bool(c["seg"]) and len(c["seg"]) >= frames[-1] + 1)
        if c["seg"] and not cam_specs[cname][2]:
            report.skip(f"realsense/{cname}/seg: too few frames ({len(c['seg'])})")
        scene.setdefault("cameras", []).append(camera_entry(cname, K, w, h, T, depth_scale=store_scale, rate_hz=rate))
    tac_names = {}
    for fname, f in fingers.items():
        first = read_image(f["image"][frames[0]], "color")
        h, w = first.shape[:2]
        name = f"digit_{fname}"
        tac_names[fname] = (name, h, w)
        scene.setdefault("tactile", []).append(tactile_entry(name, "digit", w, h, rate))
    base = _get(data, "allegro", "base_pose")
    if hand_urdf and q is not None:
        hand: dict[str, Any] = {"urdf": hand_urdf}
        if base is not None:
            hand["T_world_base"] = {"matrix": _pose_matrix(base, "allegro.base_pose", pkl).tolist()}
        tips = {"index": "link_3.0_tip", "middle": "link_7.0_tip", "ring": "link_11.0_tip", "thumb": "link_15.0_tip"}
        hand["sensors"] = [
            {
                "sensor": tac_names[f][0],
                "link": tips[f],
                "T_link_sensor": {"xyz": [0.022, 0.0, 0.015], "rpy": [0.0, 1.5707963, 0.0]},
            }
            for f in tac_names
            if f in tips
        ]
        hand["joint_names"] = ALLEGRO_JOINTS
        scene["hand"] = hand
        report.note("hand: DIGIT-Allegro URDF from shared data; T_link_sensor is the vtrack default mount")
    if not cam_specs and not tac_names and q is None and obj is None:
        # Only timestamps: writing a session would give an empty one that later commands choke on.
        raise InputError(
            "nothing to import: no realsense/<camera> images + depth.npz, no allegro/<finger> "
            "images, no allegro.joint_state and no object.pose",
            path=pkl,
            expected="at least one sensor stream",
            got=f"keys {sorted(map(str, data))}",
        )
    scene_dict = finalize_scene(scene, source=pkl)

    # --- write --------------------------------------------------------------------------------
    sinfo = _get(data, "digit_info")
    info = {"importer": "feelsight", "source": str(src)}
    if isinstance(sinfo, dict):
        info["sensor_info"] = {
            k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v)
            for k, v in sinfo.items()
            if isinstance(v, (int, float, str, list, np.ndarray))
        }
    import cv2

    with SessionWriter(out, scene_dict, overwrite=overwrite, flush_every=flush_every, info=info) as w:
        write_scene_yaml(w, scene_dict)
        from vtrack.io.streams import camera_stream, tactile_stream
        from vtrack.scene.load import scene_from_dict

        sc = scene_from_dict(scene_dict, check_files=False)
        for cname, (_d, _s, with_mask) in cam_specs.items():
            w.add_stream(f"camera/{cname}", camera_stream(sc.camera_by_name(cname), with_mask=with_mask))
        for fname, (name, h, wd) in tac_names.items():
            w.add_stream(f"tactile/{name}", tactile_stream(sc.tactile_by_name(name)))
            f = fingers[fname]
            if f["depth"] or f["mask"]:
                fields = {}
                if f["depth"]:
                    fields["depth_u8"] = FieldSpec((h, wd), "uint8", "raw 8-bit tactile depth (sim)")
                if f["mask"]:
                    fields["contact"] = FieldSpec((h, wd), "uint8", "bool")
                w.add_stream(
                    f"gt/tactile_raw/{name}",
                    StreamSpec(
                        kind="tactile_gt_raw",
                        frame=f"sensor/{name}",
                        rate_hz=rate,
                        fields=fields,
                        attrs={"sensor": name},
                    ),
                )
        if q is not None:
            w.add_stream("joints", joints_stream(ALLEGRO_JOINTS, rate_hz=rate))
        if obj is not None:
            w.add_stream("gt/object_pose", pose_stream(rate_hz=rate))

        for i in frames:
            ti = float(t[i])
            for cname, (depth, scale, with_mask) in cam_specs.items():
                c = cams[cname]
                rgb = cv2.cvtColor(read_image(c["image"][i], "color"), cv2.COLOR_BGR2RGB)
                d = encode_depth(depth[i], scale)
                vals = {"rgb": rgb, "depth": d}
                if with_mask:
                    vals["mask"] = (read_image(c["seg"][i], "gray") > 127).astype(np.uint8)
                _check_shape(vals["rgb"], (d.shape[0], d.shape[1], 3), c["image"][i])
                w.append(f"camera/{cname}", ti, **vals)
            for fname, (name, h, wd) in tac_names.items():
                f = fingers[fname]
                img = read_image(f["image"][i], "color")
                _check_shape(img, (h, wd, 3), f["image"][i])
                w.append(f"tactile/{name}", ti, image=img)
                if f["depth"] or f["mask"]:
                    vals = {}
                    if f["depth"]:
                        vals["depth_u8"] = read_image(f["depth"][i], "gray")
                        _check_shape(vals["depth_u8"], (h, wd), f["depth"][i])
                    if f["mask"]:
                        m = read_image(f["mask"][i], "gray")
                        _check_shape(m, (h, wd), f["mask"][i])
                        vals["contact"] = (m > 127).astype(np.uint8)
                    w.append(f"gt/tactile_raw/{name}", ti, **vals)
            if q is not None:
                if not np.all(np.isfinite(q[i])):
                    report.skip("joint rows with NaN/Inf")
                else:
                    w.append("joints", ti, q=q[i])
            if obj is not None:
                if not np.all(np.isfinite(obj[i])):
                    report.skip("object poses with NaN/Inf")
                else:
                    w.append("gt/object_pose", ti, T_world_object=obj[i])
        w.flush()
        report.frames = {k: v["n"] for k, v in w._streams.items()}
    extra = max(0, len(t) - len(frames) - int(report.skipped.get("frames with non-increasing time", 0)))
    if extra and max_frames is not None:
        report.note(f"--max-frames: {extra} later frames not imported")
    report.seconds = time.perf_counter() - t_start
    return report


def _check_shape(a: np.ndarray, shape: tuple[int, ...], path: Path) -> None:
    if a.shape != shape:
        raise InputError(
            "image size differs from the first frame of this sensor", path=path, expected=str(shape), got=a.shape
        )
