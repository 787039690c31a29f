"""The frames layer runs the tactile images of a time step through their pipelines together
(``TouchSource.contacts`` -> ``contact_only_many``): the frames equal those built sensor by sensor."""

from __future__ import annotations

import numpy as np


def test_frames_touch_batched_equals_one_by_one(tiny_session, monkeypatch):
    from vtrack.frames.session import SessionFrames

    sf = SessionFrames(tiny_session, ("touch",))
    raws = [sf.read(k) for k in range(0, len(sf), max(1, len(sf) // 6))]
    assert all(len(r["touch"]) >= 2 for r in raws)
    calls = []
    orig = type(sf.touch).contacts

    def counted(self, frames):
        calls.append(len(frames))
        return orig(self, frames)

    monkeypatch.setattr(type(sf.touch), "contacts", counted)
    batched = [sf.build(r) for r in raws]
    assert calls and min(calls) >= 2  # one batched call per time step
    # reference: each sensor alone through contact() (the one-by-one path)
    monkeypatch.setattr(type(sf.touch), "contacts", lambda self, fr: [self.contact(s, raw) for s, raw in fr])
    single = [sf.build(r) for r in raws]
    n_touch = 0
    for a, b in zip(batched, single, strict=True):
        assert set(vars(a)) == set(vars(b))
        for key, va in vars(a).items():
            vb = vars(b)[key]
            if isinstance(va, np.ndarray):
                np.testing.assert_array_equal(va, vb, err_msg=key)
        n_touch += len(a.touch_points)
    assert n_touch > 0  # contacts were there to compare
