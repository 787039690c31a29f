"""Evaluation metrics: reconstruction (F-score, Chamfer, normal consistency) and pose (ADD, ADD-S).

Light to import (numpy, scipy, trimesh only inside functions).
"""
