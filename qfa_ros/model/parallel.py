"""Run independent chains of GIL-free calls on a few threads (the triad's axes)."""

from collections import deque
from concurrent.futures import ThreadPoolExecutor
import os
import threading

from threadpoolctl import threadpool_limits

_POOL_LOCK = threading.Lock()  # protects the creation of _POOL
_POOL = None


def available_cores():
    """Return the number of CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def single_threaded_blas():
    """
    Return a context manager in which BLAS and LAPACK run on the calling thread only.

    The model's matrices are 3x3 at most, yet one ``scipy.linalg.expm`` or ``solve``
    wakes OpenBLAS's helper thread, which then spins for about 0.1 s: on two cores it
    takes the core the axes' threads (or a second fleet worker, or the publishing
    thread) would use. Used as a context (``with single_threaded_blas():``) around such
    calls, or called once by an entry point to keep the whole process on one BLAS thread.
    """
    return threadpool_limits(limits=1, user_api='blas')


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

    A chain is a sequence of callables without arguments that must run one after the
    other (the time slices of one axis); different chains share nothing. The calls are
    meant to release the GIL (numba ``nogil=True``). A free thread takes the next call of
    the idle chain with the most calls left, so three chains on two threads keep both
    busy (a makespan of about 3/2 of one chain, not 2). The calling thread is one of the
    workers, so progress never waits for the pool. The first exception is re-raised
    after every thread has stopped.
    """
    pending = [deque(chain) for chain in chains]
    busy = [False] * len(pending)
    errors = []
    # Guards pending, busy and errors; notified whenever a call ends.
    condition = threading.Condition()

    def work():
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
            except BaseException as error:  # noqa: B902 - handed to the caller below
                with condition:
                    errors.append(error)
                    condition.notify_all()
                return
            with condition:
                busy[k] = False
                condition.notify_all()

    helpers = max(0, min(workers, len(pending)) - 1)
    futures = [_pool().submit(work) for _ in range(helpers)]
    work()
    for future in futures:
        future.result()
    if errors:
        raise errors[0]
