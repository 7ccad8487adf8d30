"""Run independent chains of GIL-free calls on a few threads (the triad's axes)."""

from collections import deque
from concurrent.futures import ThreadPoolExecutor
import os
import threading

_POOL_LOCK = threading.Lock()  # protects the creation of _POOL
_POOL = None


def available_cores():
    """Return the number of CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _pool():
    # Helper threads, made once; a call queued behind a busy helper only finds no work.
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=max(1, available_cores() - 1),
                                       thread_name_prefix='qfa-chain')
        return _POOL


def run_chains(chains, workers):
    """
    Run every chain's calls in order, the chains concurrently on up to ``workers`` threads.

    :func:`start_chains` then :meth:`ChainRun.join`.
    """
    start_chains(chains, workers).join()


def start_chains(chains, workers):
    """
    Start running every chain's calls in order, the chains concurrently; return the run.

    A chain is a sequence of callables without arguments that must run one after the
    other (the time slices of one axis); different chains share nothing. The calls are
    meant to release the GIL (numba ``nogil=True``). A free thread takes the next call of
    the idle chain with the most calls left, so three chains on two threads keep both
    busy (a makespan of about 3/2 of one chain, not 2). Up to ``workers - 1`` helper
    threads start at once; the calling thread may do other work (holding the GIL is
    fine: the calls do not need it) and then joins them with :meth:`ChainRun.join`, so
    progress never waits for the pool.
    """
    run = ChainRun(chains)
    helpers = max(0, min(workers, len(chains)) - 1)
    run.futures = [_pool().submit(run.work) for _ in range(helpers)]
    return run


class ChainRun:
    """Chains being run by :func:`start_chains`; :meth:`join` waits for all of them."""

    def __init__(self, chains):
        self.pending = [deque(chain) for chain in chains]
        self.busy = [False] * len(self.pending)
        self.errors = []
        self.futures = []
        # Guards pending, busy and errors; notified whenever a call ends.
        self.condition = threading.Condition()

    def work(self):
        """Run calls until none is left (or one failed); any thread may call this."""
        pending, busy, errors, condition = self.pending, self.busy, self.errors, \
            self.condition
        while True:
            with condition:
                while True:
                    if errors:
                        return
                    free = [k for k, calls in enumerate(pending) if calls and not busy[k]]
                    if free:
                        break
                    if not any(pending):
                        return
                    condition.wait()
                k = max(free, key=lambda index: len(pending[index]))
                busy[k] = True
                call = pending[k].popleft()
            try:
                call()
            except BaseException as error:  # noqa: B902 - handed to the caller by join
                with condition:
                    errors.append(error)
                    condition.notify_all()
                return
            with condition:
                busy[k] = False
                condition.notify_all()

    def join(self):
        """Work on the calls left with the calling thread; re-raise the first failure."""
        self.work()
        for future in self.futures:
            future.result()
        self.futures = []
        if self.errors:
            raise self.errors[0]
