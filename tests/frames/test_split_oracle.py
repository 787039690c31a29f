"""The split segmentation oracles (``gt_colour`` / ``gt_points``): each gives the renderer's mask to exactly one of the
mask's two uses (colour feature tracks, depth points) and leaves the other to the blind pipeline, and a run using one
is labelled an oracle."""

import numpy as np
import pytest


def _frames(session, seg: str, n: int) -> list:
    from vtrack.frames.session import SessionFrames

    fr = SessionFrames(session, modalities=("vision",), segmentation=seg, colour=True)
    return [fr.frame(i)[0] for i in range(n)]


def test_each_split_oracle_swaps_exactly_one_use(tiny_session):
    n = 6
    pipe, gt = _frames(tiny_session, "pipeline", n), _frames(tiny_session, "gt", n)
    gc, gp = _frames(tiny_session, "gt_colour", n), _frames(tiny_session, "gt_points", n)
    # the two masks differ on this session, so the comparisons below can tell the sources apart
    assert any(a.vision_points.shape != b.vision_points.shape for a, b in zip(pipe, gt, strict=True))
    assert sum(len(f.colour_ids) for f in pipe) > 0 and sum(len(f.colour_ids) for f in gt) > 0
    for p, g, c, q in zip(pipe, gt, gc, gp, strict=True):
        np.testing.assert_array_equal(c.vision_points, p.vision_points)  # gt_colour: points from the pipeline
        np.testing.assert_array_equal(c.colour_ids, g.colour_ids)  # ... tracks on the renderer's mask
        np.testing.assert_array_equal(c.colour_points, g.colour_points)
        np.testing.assert_array_equal(q.vision_points, g.vision_points)  # gt_points: the reverse
        np.testing.assert_array_equal(q.colour_ids, p.colour_ids)
        np.testing.assert_array_equal(q.colour_points, p.colour_points)


@pytest.mark.parametrize("seg", ["gt_colour", "gt_points"])
def test_split_oracle_runs_are_not_blind(tiny_session, seg):
    from vtrack.tracking.run import track_session

    m = track_session(tiny_session, "", shape="slam", segmentation=seg, max_frames=8, write=False)
    assert m["oracle"] == ["segmentation"] and m["blind"] is False
    assert np.isfinite(m["motion_err_mm"])


def test_unknown_segmentation_names_the_choices(tiny_session):
    from vtrack.errors import InputError
    from vtrack.frames.session import SessionFrames

    with pytest.raises(InputError, match="gt_colour"):
        SessionFrames(tiny_session, segmentation="gt_depth")


def test_segmentation_options_reach_the_segmenter_and_typos_are_refused(tiny_session):
    from vtrack.errors import InputError
    from vtrack.frames.session import SessionFrames

    fr = SessionFrames(tiny_session, modalities=("vision",), segmentation_opts={"colour_grow_px": 1})
    assert all(c.segmenter.opt.colour_grow_px == 1 for c in fr.cams)
    assert all(c.segmenter.opt.colour_grow_px == 0 for c in SessionFrames(tiny_session, modalities=("vision",)).cams)
    with pytest.raises(InputError, match="colour_grw_px"):
        SessionFrames(tiny_session, segmentation_opts={"colour_grw_px": 1})
