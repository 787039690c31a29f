"""Dome (TacTip / FusionTouch-style) marker sensor: simulator, marker graph, coarse-to-fine GNN.

Modules: :mod:`.model` (dome geometry, templates, fisheye camera), :mod:`.simulate` (training data with
exact ground truth), :mod:`.markers` (marker extraction, S5 descriptors, Delaunay graph), :mod:`.nets`
(GNN and CNN reconstruction nets, force heads; imports torch), :mod:`.train`, :mod:`.metrics`,
:mod:`.evaluate`, :mod:`.reconstruct` (the ``dome`` registry component) and :mod:`.tactip` (real frames).
Importing this package does not import torch.
"""
