"""The live pipeline's mailboxes: a stage may queue a few frames per stream (a burst is absorbed, not lost) and take
every pending frame at once (one helper round trip for the four tactile images of a time step); whatever is never
processed is counted as dropped."""

from __future__ import annotations

import numpy as np

from vtrack.live.pipeline import Consumer, LivePipeline, _Worker
from vtrack.live.sources import FrameEvent, QueueSource


class Batch(Consumer):
    name = "batch"
    max_pending = 2
    batch = True

    def __init__(self, lose: set[int] | None = None) -> None:
        self.batches: list[list[tuple[str, int]]] = []
        self.lose = lose or set()
        self.offload_cpu_s = 0.0

    def process_batch(self, events):
        self.batches.append([(ev.stream, round(ev.t * 60)) for ev in events])
        self.offload_cpu_s = 0.004 * len(events)  # as if a helper process had spent 4 ms per frame
        return [round(ev.t * 60) not in self.lose for ev in events]


def _ev(stream: str, i: int) -> FrameEvent:
    return FrameEvent(stream, i / 60, i, {"image": np.zeros(2)})


def test_mailbox_keeps_max_pending_per_stream_and_hands_a_batch_everything_oldest_first():
    w = _Worker(Batch())
    for i in range(5):
        w.put(_ev("tactile/a", i))
    w.put(_ev("tactile/b", 3))
    assert w.stats.dropped == {"tactile/a": 3} and w.stats.received == {"tactile/a": 5, "tactile/b": 1}
    got = w._take()
    assert [(e.stream, e.index) for e in got] == [("tactile/a", 3), ("tactile/b", 3), ("tactile/a", 4)]
    assert not w.slots

    one = _Worker(Consumer())  # default: one slot per stream, the newest frame, one at a time
    for i in range(3):
        one.put(_ev("camera/c", i))
    one.put(_ev("joints", 1))
    assert one.stats.dropped == {"camera/c": 2}
    assert [e.stream for e in one._take()] == ["joints"] and [e.index for e in one._take()] == [2]


def test_a_batch_stage_counts_each_frame_it_lost_and_shares_its_cpu_among_those_it_processed():
    import threading
    import time

    src = QueueSource()

    def feed() -> None:  # two sensors at 200 Hz into a stage that takes 12 ms per batch
        for i in range(12):
            for s in ("tactile/a", "tactile/b"):
                src.push(s, i / 60, {"image": np.zeros(2)})
            time.sleep(0.005)
        src.close()

    class Slow(Batch):
        def process_batch(self, events):
            time.sleep(0.012)
            return super().process_batch(events)

    c = Slow(lose={5})
    threading.Thread(target=feed, daemon=True).start()
    res = LivePipeline(src, [c]).run()
    st = res["consumers"]["batch"]["streams"]
    seen = [f for b in c.batches for f in b]
    assert len(seen) == len(set(seen))  # each frame handed over once
    assert max(len(b) for b in c.batches) >= 3  # the frames that waited went together
    assert all([i for _, i in b] == sorted(i for _, i in b) for b in c.batches)  # oldest first
    for s in ("tactile/a", "tactile/b"):
        done = [i for x, i in seen if x == s and i != 5]
        assert st[s]["received"] == 12 and st[s]["processed"] == len(done)
        assert st[s]["dropped"] == 12 - len(done)  # replaced in the mailbox or lost in the batch (frame 5)
        assert st[s]["cpu_ms_mean"] >= 4.0  # the helper's CPU, per frame processed
