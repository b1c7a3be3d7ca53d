"""The sampler without HTTP (serve/sampler.py), driven with asyncio. Its
jobs are plain functions that run until the test sets an Event, so no test
depends on how fast the machine is."""

import asyncio
import threading
from types import SimpleNamespace

import pytest

from sinshape.serve import sampler as sampling
from sinshape.serve.sampler import ClientGone, NoSlot, OutOfTime, Sampler


def finished(size: int = 1):
    """A result: the sampler reads only its bytes."""
    return SimpleNamespace(body=bytes(size))


class Held:
    """A job's work that runs until `release` is set, calling its checkpoint
    meanwhile (unless told not to); counts its runs and says how each ended."""

    def __init__(self, checks: bool = True):
        self.release, self.started, self.checks = threading.Event(), threading.Event(), checks
        self.runs, self.ended = 0, []

    def __call__(self, checkpoint):
        self.runs += 1
        self.started.set()
        try:
            while not self.release.wait(0.002):
                if self.checks:
                    checkpoint()
        except sampling.Cancelled:
            self.ended.append("cancelled")
            raise
        self.ended.append("done")
        return finished()


async def until(condition, what: str):
    """Yield to the loop until condition() holds (a guard against a hang, not a time asserted)."""
    for _ in range(10_000):
        if condition():
            return
        await asyncio.sleep(0.002)
    raise AssertionError(f"never: {what}")


def test_two_identical_jobs_share_one_computation_then_the_cache():
    async def run():
        sampler = Sampler(slots=2, timeout=60, cache_bytes=1000)
        work = Held()
        waiters = [asyncio.ensure_future(sampler.get("job", work)) for _ in range(2)]
        await until(lambda: work.started.is_set() and sampler.waiting.get("job") == 2, "both waiting")
        work.release.set()
        (first, first_hit), (second, second_hit) = await asyncio.gather(*waiters)
        again, hit = await sampler.get("job", work)
        sampler.close()
        return work, (first, second, again), (first_hit, second_hit, hit)

    work, (first, second, again), hits = asyncio.run(run())
    assert work.runs == 1 and first is second is again
    assert hits == (False, False, True)


def test_a_job_whose_clients_all_leave_is_stopped_and_frees_its_slot(monkeypatch):
    monkeypatch.setattr(sampling, "DISCONNECT_POLL", 0.005)

    async def run():
        sampler = Sampler(slots=1, timeout=60, cache_bytes=1000)
        work, left = Held(), [False, False]

        def leaves(i):
            async def gone():
                return left[i]
            return gone

        waiters = [asyncio.ensure_future(sampler.get("job", work, leaves(i))) for i in range(2)]
        await until(work.started.is_set, "the job started")
        left[0] = True
        with pytest.raises(ClientGone):
            await waiters[0]
        one_left = (sampler.running, list(work.ended))  # the other client still waits: the job goes on
        left[1] = True
        with pytest.raises(ClientGone):
            await waiters[1]
        await until(lambda: sampler.running == 0, "the slot freed")
        after, hit = await sampler.get("next", lambda checkpoint: finished())  # the only slot: free again
        sampler.close()
        return sampler, work, one_left, (after, hit)

    sampler, work, one_left, (after, hit) = asyncio.run(run())
    assert one_left == (1, []) and work.ended == ["cancelled"]
    assert not hit and after.body == bytes(1)
    assert "job" not in sampler.cache and not sampler.pending and not sampler.waiting


def test_a_job_over_the_time_limit_is_stopped():
    async def run():
        sampler = Sampler(slots=1, timeout=0.05, cache_bytes=1000)
        work = Held()
        with pytest.raises(OutOfTime, match="longer than the 0.05 s limit"):
            await sampler.get("job", work)
        await until(lambda: sampler.running == 0, "the slot freed")
        sampler.close()
        return sampler, work

    sampler, work = asyncio.run(run())
    assert work.ended == ["cancelled"] and "job" not in sampler.cache and not sampler.pending


def test_no_slot_free_within_the_time_limit():
    """The only slot is held by work that never reaches a checkpoint: the next job gets no slot."""
    async def run():
        sampler = Sampler(slots=1, timeout=0.05, cache_bytes=1000)
        stubborn = Held(checks=False)
        holding = asyncio.ensure_future(sampler.get("stubborn", stubborn))
        await until(stubborn.started.is_set, "the first job started")
        with pytest.raises(NoSlot, match="no sampling slot came free within 0.05 s"):
            await sampler.get("next", lambda checkpoint: finished())
        with pytest.raises(OutOfTime):
            await holding
        stubborn.release.set()
        await until(lambda: sampler.running == 0, "the slot freed")
        sampler.close()
        return stubborn

    assert asyncio.run(run()).ended == ["done"]


def test_the_cache_keeps_the_most_recent_within_its_bytes_and_its_count():
    async def fill(sampler, keys, size):
        return [await sampler.get(key, lambda checkpoint: finished(size)) for key in keys]

    async def run():
        by_bytes = Sampler(slots=1, timeout=60, cache_bytes=100)
        await fill(by_bytes, "abcd", 25)  # 100 bytes: all kept
        (_, hit), = await fill(by_bytes, "a", 25)  # used again: b is now the oldest
        await fill(by_bytes, "e", 25)  # 125 bytes: b goes
        await fill(by_bytes, "f", 26)  # over a quarter of the cache: not kept
        by_count = Sampler(slots=1, timeout=60, cache_bytes=1000, cache_entries=2)
        await fill(by_count, "xyz", 1)
        for sampler in (by_bytes, by_count):
            sampler.close()
        return hit, by_bytes, by_count

    hit, by_bytes, by_count = asyncio.run(run())
    assert hit and list(by_bytes.cache) == ["c", "d", "a", "e"] and by_bytes.cached_bytes == 100
    assert list(by_count.cache) == ["y", "z"] and by_count.cached_bytes == 2
    assert by_count.counts() == {"sampling": 0, "most_sampling": 1, "in_flight": 0, "cached_files": 2,
                                 "cached_bytes": 2}
