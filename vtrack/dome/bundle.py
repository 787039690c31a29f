"""Dome model bundles (``vtrack/dome/weights/{gnn,cnn}.pt``): the on-disk format, building and loading.

Inference (:mod:`vtrack.dome.reconstruct`) needs only this module, never the training code. A bundle is a
``torch.save`` dict: ``version`` (:data:`BUNDLE_VERSION`), ``kind`` (gnn | cnn), ``cfg`` (DomeConfig),
``train`` (TrainConfig), ``info``, ``contact_calib`` (Platt a, b), ``recon`` (float16 state dict) and
``force_p`` / ``force_nop`` (force nets with / without the internal pressure).

Version 3 adds ``force_archs`` ({head key: architecture}, ``vtrack.dome.force.ARCHS``: ``decoder_film`` =
:class:`nets.ForceHead` on the decoder features, ``patch_graph`` / ``patch_graph_plain`` = the S18-S23 GNN +
patch net, ``cnn_film`` = FiLM on the CNN feature map) and ``force_arch`` (that of ``p``). Besides ``p`` / ``nop``
(the main nets) a bundle may hold ablation heads under other keys (``force_<key>``, e.g. ``legacy_p`` = the
decoder-feature head, ``plain_p`` = the S18-S20 net without the additions). The head key's suffix says whether
it reads the pressure (``p``) or not (``nop``). Versions 1-2: ``force_p`` / ``force_nop`` are ``decoder_film``.

Versions: 1 = written before the field existed (no ``version`` key): missing DomeConfig / TrainConfig keys
take the behaviour of that time (reference frame at P = 0; 4-NN, 3 layers, no edge strain, no still-L1);
2 = every config key stored explicitly, nothing is guessed on load.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from vtrack.dome.model import DomeConfig, DomeGeometry
from vtrack.errors import InputError

#: Format version written by :func:`save_bundle`.
BUNDLE_VERSION = 3
#: TrainConfig keys a version-1 bundle may lack, with the behaviour it was trained with.
_V1_TRAIN_DEFAULTS = {"gnn_k": 4, "gnn_layers": 3, "gnn_edge_strain": False, "still_l1": 0.0}


@dataclass
class TrainConfig:
    n_train: int = 2000
    n_test: int = 300
    seed: int = 0
    test_seed: int = 12345
    epochs_coarse: int = 8
    epochs_fine: int = 6
    epochs_force: int = 20
    batch: int = 32
    lr: float = 2e-3
    hidden: int = 64
    threads: int = 1
    gnn_k: int = 4  # markers interpolated per coarse template point
    gnn_layers: int = 3  # GINE layers
    gnn_edge_strain: bool = True  # reference-relative edge strain attributes (features.edge_strain)
    #: weight of an L1 term (mean error norm, mm) on the non-contact points, next to their L2 term: L2 alone
    #: leaves ~0.01 mm of phantom deformation on the ~80 % of the dome that does not move; L1 pulls it to 0
    still_l1: float = 2.0
    #: reconstruction losses: "mix" (L2 region terms + L1 on still points, L2 Laplacian / edge vs GT) or "paper"
    #: (FusionTouch S9, S14-S17: L1 region terms, L1 Laplacian and edge-length terms); see train.recon_loss
    recon_loss: str = "mix"
    #: epochs of the S18-S23 force nets (GNN + patch / CNN feature map; best validation checkpoint kept)
    epochs_force_net: int = 12


def read_bundle(path: str | Path) -> dict:
    """The raw bundle dict. ``weights_only=True``: tensors and plain containers only, so a bundle file can never
    run code (torch's pickle would otherwise execute whatever a crafted file asks for)."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise InputError("dome model bundle not found", path=path, expected="a .pt file from `vtrack dome train`")
    try:
        b = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - corrupt zip, pickle with objects, truncated file, ...
        raise InputError(f"not a dome model bundle ({type(e).__name__})", path=path) from None
    missing = [k for k in ("kind", "cfg", "train", "recon") if not isinstance(b, dict) or k not in b]
    if missing:
        raise InputError("dome model bundle incomplete", path=path, field=",".join(missing))
    bundle_version(b)
    return b


def bundle_version(bundle: dict) -> int:
    """The format version of a loaded bundle dict (1 when it predates the field); InputError for a newer one."""
    v = int(bundle.get("version", 1))
    if not 1 <= v <= BUNDLE_VERSION:
        raise InputError("dome bundle from a newer vtrack", field="version", expected=f"<= {BUNDLE_VERSION}", got=v)
    return v


def bundle_train_config(bundle: dict) -> TrainConfig:
    """The TrainConfig a bundle was trained with (version 1: missing options take their old behaviour)."""
    legacy = _V1_TRAIN_DEFAULTS if bundle_version(bundle) == 1 else {}
    try:
        return TrainConfig(**{**legacy, **bundle["train"]})
    except TypeError as e:  # unknown or missing keys
        raise InputError(f"dome bundle training config does not match this vtrack ({e})", field="train") from None


def bundle_dome_config(bundle: dict) -> DomeConfig:
    """The DomeConfig of a bundle (version 1: :meth:`DomeConfig.from_dict` fills the old protocol)."""
    d = bundle["cfg"]
    try:
        return DomeConfig.from_dict(d) if bundle_version(bundle) == 1 else DomeConfig(**d)
    except TypeError as e:  # unknown or missing keys
        raise InputError(f"dome bundle sensor config does not match this vtrack ({e})", field="cfg") from None


def build_model(
    kind: str, geo: DomeGeometry, hidden: int = 64, gnn_k: int = 4, gnn_layers: int = 3, gnn_edge_strain: bool = True
):
    from vtrack.dome.nets import DomeCNN, DomeGNN

    if kind == "gnn":
        return DomeGNN(geo, hidden, gnn_layers, gnn_k, gnn_edge_strain)
    if kind == "cnn":
        return DomeCNN(geo, hidden)
    raise ValueError(f"unknown model kind {kind!r} (gnn | cnn)")


def save_bundle(path: Path, kind: str, model, heads: dict, cfg: DomeConfig, tc: TrainConfig, info: dict) -> None:
    """Weights in float16 (they are small; halves the shipped size) plus configs. ``heads``: {key: force net}
    with keys ending in ``p`` (reads the pressure) or ``nop``; ``p`` / ``nop`` are the main nets."""
    import torch

    def half(sd):
        return {k: (v.half() if v.is_floating_point() else v) for k, v in sd.items()}

    archs = {k: getattr(h, "arch", "decoder_film") for k, h in heads.items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(
        {
            "version": BUNDLE_VERSION,
            "kind": kind,
            "cfg": cfg.to_dict(),
            "train": asdict(tc),
            "info": info,
            "contact_calib": list(model.decoder.contact_calib),
            "recon": half(model.state_dict()),
            "force_arch": archs.get("p", archs.get("nop", "decoder_film")),
            "force_archs": archs,
            **{f"force_{k}": half(h.state_dict()) for k, h in heads.items()},
        },
        path,
    )


def load_bundle(path: Path, with_heads: bool = True):
    """-> (model, {"p": net, "nop": net, ...ablation heads}, DomeConfig, info) in eval mode, float32."""

    from vtrack.dome.force import ARCHS, build_force
    from vtrack.dome.nets import ForceHead

    b = read_bundle(path)
    cfg = bundle_dome_config(b)
    geo = DomeGeometry(cfg)
    hidden = b["train"]["hidden"]
    tc = bundle_train_config(b)
    model = build_model(b["kind"], geo, hidden, tc.gnn_k, tc.gnn_layers, tc.gnn_edge_strain)
    model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in b["recon"].items()})
    model.decoder.contact_calib = tuple(float(v) for v in b.get("contact_calib", (1.0, 0.0)))
    archs = b.get("force_archs") if bundle_version(b) >= 3 else None
    if archs is None:
        archs = {k: "decoder_film" for k in ("p", "nop") if f"force_{k}" in b}
    heads = {}
    for key, arch in archs.items() if with_heads else ():
        if arch not in ARCHS:
            raise InputError("unknown force architecture in dome bundle", path=path, field="force_archs", got=arch)
        if f"force_{key}" not in b or not key.endswith("p"):
            raise InputError("dome bundle force head missing or misnamed", path=path, field=f"force_{key}")
        use_p = not key.endswith("nop")
        if arch == "decoder_film":
            h = ForceHead(geo, hidden, 2 * hidden, use_pressure=use_p)
        else:
            h = build_force(arch, cfg.pressure_max_kpa, use_p, hidden)
        h.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in b[f"force_{key}"].items()})
        heads[key] = h.eval()
    return model.eval(), heads, cfg, b.get("info", {})


def weights_dir() -> Path:
    return Path(__file__).resolve().parent / "weights"
