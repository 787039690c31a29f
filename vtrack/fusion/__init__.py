"""World-frame visuo-tactile fusion: unified cloud, TSDF and neural SDF reconstruction.

Modules (import the one you need; nothing heavy is imported here):
- :mod:`vtrack.fusion.cloud` unified vision+touch point cloud (numpy only);
- :mod:`vtrack.fusion.observations` session -> per-frame observations in the object frame;
- :mod:`vtrack.fusion.tsdf` Open3D tensor TSDF (never imports torch);
- :mod:`vtrack.fusion.neural_sdf` pure-torch neural SDF (never imports open3d);
- :mod:`vtrack.fusion.reconstruct` ``reconstruct_session`` used by ``vtrack reconstruct``.
"""
