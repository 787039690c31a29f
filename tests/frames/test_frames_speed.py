"""Exact fast paths of the frames layer (issue #19, SLAM speed): they give the values of the plain code."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vtrack.frames.session import upsample_mask


@pytest.mark.parametrize("small, big", [((120, 160), (480, 640)), ((60, 80), (120, 320)), ((121, 161), (481, 641))])
def test_upsample_mask_equals_a_nearest_resize(small, big):
    rng = np.random.default_rng(0)
    m = np.zeros(small, bool)
    m[20:50, 30:70] = rng.random((30, 40)) > 0.3  # a blob with holes, away from the borders
    m[-1, -1] = True  # and a pixel in the far corner
    ref = cv2.resize(m.astype(np.uint8), (big[1], big[0]), interpolation=cv2.INTER_NEAREST) > 0
    for mask in (m, m.astype(np.uint8) * 255, np.zeros(small, bool)):
        out = upsample_mask(mask, big)
        want = ref if mask.any() else np.zeros(big, bool)
        assert out.dtype == bool and out.shape == big and np.array_equal(out, want)
