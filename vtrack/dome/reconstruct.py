"""``DomeReconstructor``: one dome-sensor image (+ internal pressure) -> dense surface, contact, force.

Registry key ``"dome"``. Loads the shipped weights (``vtrack/dome/weights/{gnn,cnn}.pt``) unless told
otherwise. Output frame: the dome frame of :mod:`vtrack.dome.model` (mm, origin at the sphere centre,
+z through the apex).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.io.jsonio import write_json


@dataclass
class DomeResult:
    """Reconstruction of one frame (lengths mm, force N, dome frame)."""

    dense_mm: np.ndarray
    faces: np.ndarray
    coarse_mm: np.ndarray
    contact_prob: np.ndarray
    force_n: np.ndarray
    n_markers: int
    graph_method: str
    ms: float
    info: dict = field(default_factory=dict)

    @property
    def valid(self) -> bool:
        """False when the input did not look like a frame of this sensor (see ``info['invalid_reason']``)."""
        return bool(self.info.get("valid", True))

    def summary(self) -> dict[str, Any]:
        if not self.valid:  # no force/indentation numbers from an image the model cannot read
            return {
                "valid": False,
                "n_markers": self.n_markers,
                "force_n": None,
                "contact_points": None,
                "max_indentation_mm": None,
                "invalid_reason": self.info.get("invalid_reason", ""),
            }
        return {
            "n_markers": self.n_markers,
            "graph": self.graph_method,
            "ms": round(self.ms, 2),
            "force_n": [round(float(v), 4) for v in self.force_n],
            "contact_points": int((self.contact_prob > 0.5).sum()),
            "max_indentation_mm": float(self.info.get("max_indentation_mm", 0.0)),
            **self.info,
        }

    def save(self, out_dir: Path) -> dict[str, Path]:
        """``mesh.ply`` (dense surface, mm), ``coarse.ply`` (coarse template + contact prob), ``result.json``."""
        import trimesh

        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        mesh = trimesh.Trimesh(self.dense_mm, self.faces, process=False)
        mesh.export(out_dir / "mesh.ply")
        cols = np.zeros((len(self.coarse_mm), 4), np.uint8)
        cols[:, 0] = (255 * self.contact_prob).astype(np.uint8)
        cols[:, 2] = 255 - cols[:, 0]
        cols[:, 3] = 255
        trimesh.PointCloud(self.coarse_mm, colors=cols).export(out_dir / "coarse.ply")
        write_json(out_dir / "result.json", {"kind": "dome", **self.summary()}, indent=1)
        return {"mesh": out_dir / "mesh.ply", "coarse": out_dir / "coarse.ply", "json": out_dir / "result.json"}


def default_weights(method: str = "gnn") -> Path:
    return Path(__file__).resolve().parent / "weights" / f"{method}.pt"


class DomeReconstructor:
    """Image -> marker graph -> coarse-to-fine surface (GNN), or image -> CNN -> same decoder.

    Args:
        method: ``"gnn"`` (default) or ``"cnn"``.
        weights: bundle file (default: the shipped ``vtrack/dome/weights/<method>.pt``).
        reference: the sensor's no-contact image (array or path), captured at the operating pressure that
            is passed to :meth:`reconstruct` (``DomeConfig.reference_at_pressure``; at P = 0 for bundles of the
            older protocol). Default: the simulator's reference frame at the frame's pressure.
    """

    def __init__(
        self, method: str = "gnn", weights: str | Path | None = None, reference: np.ndarray | str | Path | None = None
    ) -> None:
        import torch

        from vtrack.dome.bundle import load_bundle
        from vtrack.dome.model import DomeGeometry

        if method not in ("gnn", "cnn"):
            raise InputError("unknown dome method", field="method", expected="gnn or cnn", got=method)
        path = Path(weights) if weights is not None else default_weights(method)
        if not path.exists():
            raise InputError("dome weights not found (train them with `vtrack dome train`)", path=path)
        self.method = method
        self.model, self.heads, self.cfg, self.info = load_bundle(path)
        self.geo = DomeGeometry(self.cfg)
        self._torch = torch
        self._fixed: tuple | None = None  # user reference: (image, markers)
        self._simulated: dict[float, tuple] = {}  # simulated references by pressure (kPa)
        if reference is not None:
            ref = self._read(reference)
            self._check_size(ref, reference if isinstance(reference, (str, Path)) else None)
            self._fixed = self._prepare_reference(ref)

    def _prepare_reference(self, ref: np.ndarray) -> tuple:
        from vtrack.dome.features import reference_markers
        from vtrack.dome.markers import check_image

        ref = check_image(ref)
        return ref, reference_markers(ref)

    def reference(self, pressure_kpa: float = 0.0) -> tuple:
        """(reference image, its markers) used for frames at ``pressure_kpa``: the user's reference, else the
        simulator's no-contact frame at the reference pressure (prepared once per pressure and cached)."""
        if self._fixed is not None:
            return self._fixed
        key = round(self.cfg.reference_pressure(pressure_kpa), 6)
        if key not in self._simulated:
            from vtrack.dome.simulate import DomeSimulator

            if len(self._simulated) >= 64:  # a session uses one pressure; bound the cache anyway
                self._simulated.pop(next(iter(self._simulated)))
            self._simulated[key] = self._prepare_reference(DomeSimulator(self.cfg).reference_image(key))
        return self._simulated[key]

    @classmethod
    def from_scene(cls, scene: Any, **opts: Any) -> DomeReconstructor:
        """Build from a scene: uses the first ``type: dome`` tactile sensor's ``background`` as reference."""
        ref = opts.pop("reference", None)
        if ref is None:
            for t in getattr(scene, "tactile", []) or []:
                if t.type == "dome" and t.background is not None:
                    ref = t.background
                    break
        return cls(reference=ref, **opts)

    @staticmethod
    def _read(image: np.ndarray | str | Path) -> np.ndarray:
        if isinstance(image, (str, Path)):
            from vtrack.io.images import read_image

            return read_image(image, "gray")
        return np.asarray(image)

    def _check_size(self, img: np.ndarray, path=None) -> None:
        S = self.cfg.image_size
        if img.shape[:2] != (S, S):
            raise InputError(
                "image of the wrong size for this model",
                path=path,
                field="image",
                expected=f"{S}x{S} px (pass resize=True to rescale)",
                got=f"{img.shape[1]}x{img.shape[0]}",
            )

    def reconstruct(
        self, image: np.ndarray | str | Path, pressure_kpa: float = 0.0, *, resize: bool = False
    ) -> DomeResult:
        """Reconstruct one frame. ``pressure_kpa`` must lie in ``[0, cfg.pressure_max_kpa]``."""
        from vtrack.dome.markers import check_image

        path = image if isinstance(image, (str, Path)) else None
        img = check_image(self._read(image), path=path)
        if img.dtype != np.uint8:
            img = np.clip(img, 0, 255).astype(np.uint8)
        if resize and img.shape != (self.cfg.image_size,) * 2:
            import cv2

            img = cv2.resize(img, (self.cfg.image_size,) * 2, interpolation=cv2.INTER_AREA)
        self._check_size(img, path)
        p = float(pressure_kpa)
        if not np.isfinite(p) or p < 0 or p > self.cfg.pressure_max_kpa:
            raise InputError(
                "internal pressure out of the trained range",
                field="pressure_kpa",
                expected=f"0 <= P <= {self.cfg.pressure_max_kpa} kPa",
                got=pressure_kpa,
            )
        from vtrack.dome.markers import extract_markers

        found = extract_markers(img)  # one detection feeds the marker graph (GNN) and the validity check
        res = self._run(img, p, found)
        ok, reason = self.marker_match(img, p, found)
        res.info["valid"] = ok
        if not ok:
            res.info["invalid_reason"] = reason
        return res

    #: fraction of the reference markers that must be found near their rest position for a frame to be read
    MIN_MATCHED_FRACTION = 0.6

    def marker_match(self, img: np.ndarray, pressure_kpa: float = 0.0, found=None) -> tuple[bool, str]:
        """Is ``img`` a frame of this sensor? (validity, reason if not).

        A real press moves markers by well under one marker spacing except inside the contact, so most
        reference (no-contact) markers have a detected marker within half a spacing. Random noise,
        blank images, other sensors and the un-rectified fisheye frames find few (measured: simulated
        presses 100 %, noise 1 %, black 0 %, the real DiffTactile frames resized 4 % and 23 %).
        ``found``: the markers of ``img`` when already detected (``markers.extract_markers``).
        """
        from scipy.spatial import cKDTree

        from vtrack.dome.features import reference_index
        from vtrack.dome.markers import extract_markers

        ref_markers = self.reference(pressure_kpa)[1]
        ref = ref_markers.centers
        found = (found if found is not None else extract_markers(img)).centers
        if len(ref) < 3:
            return False, "the reference image has fewer than 3 markers"
        spacing = reference_index(ref_markers, self.cfg.image_size / 2.0)[1]  # built once per reference
        frac = float((cKDTree(found).query(ref)[0] < 0.5 * spacing).mean()) if len(found) else 0.0
        if frac < self.MIN_MATCHED_FRACTION:
            return False, (
                f"not a frame of this dome sensor: {frac:.0%} of the {len(ref)} reference markers found "
                f"near their rest position (need >= {self.MIN_MATCHED_FRACTION:.0%}; "
                f"{len(found)} markers detected)"
            )
        return True, ""

    def _run(self, img: np.ndarray, p: float, markers=None) -> DomeResult:
        """Network pass on a checked frame; ``markers``: its detected markers when already extracted."""
        torch = self._torch
        from vtrack.dome.features import collate_graphs, graph_arrays, image_batch

        t0 = time.perf_counter()
        n_markers, method = 0, "image"
        ref_img, ref_markers = self.reference(p)
        infl = torch.tensor([float(self.geo.reference_inflation_mm(p))], dtype=torch.float32)
        with torch.no_grad():
            if self.method == "gnn":
                g = graph_arrays(img, ref_markers, self.geo, markers)
                n_markers, method = len(g["x"]), g["method"]
                batch = collate_graphs([g])
            else:
                batch = image_batch(img, ref_img)
            batch["ref_inflation_mm"] = infl
            out = self.model(batch)
            force = np.zeros(3, np.float32)
            head = self.heads.get("p")
            if head is not None:
                if getattr(head, "needs_patches", False):  # S18-S23 net: marker-centred [image, reference] patches
                    from vtrack.dome.force import centers_from_x, marker_patches

                    c = centers_from_x(g["x"], self.cfg.image_size)
                    batch["patches"] = torch.from_numpy(marker_patches(img, ref_img, c)).float() / 255.0
                force = head.run(out, batch, torch.tensor([p]))[0].numpy()
        ms = (time.perf_counter() - t0) * 1e3
        dense = out["dense"][0].numpy().astype(np.float64)
        coarse = out["coarse"][0].numpy().astype(np.float64)
        prob = self.model.decoder.contact_prob(out["contact_logit"][0]).numpy().astype(np.float64)
        for name, arr in (("dense", dense), ("coarse", coarse), ("force", force)):
            if not np.all(np.isfinite(arr)):  # never let NaN/Inf out silently
                raise InputError("non-finite network output", field=name, expected="finite values")
        rest = self.model.decoder.dense_rest.numpy()  # may be a subset (benchmark operating points)
        # indentation from the reference (no-contact) state at this pressure, not from the deflated rest shape
        ind = np.linalg.norm(rest, axis=1) + float(infl[0]) - np.linalg.norm(dense, axis=1)
        faces = self.geo.dense_faces if len(dense) == self.cfg.n_dense else np.zeros((0, 3), np.int64)
        info = {
            "max_indentation_mm": float(max(0.0, ind.max())),
            "pressure_kpa": p,
            "low_marker_count": bool(self.method == "gnn" and n_markers < 0.5 * self.cfg.n_markers),
        }
        return DomeResult(dense, faces, coarse, prob, force.astype(np.float64), n_markers, method, ms, info)
