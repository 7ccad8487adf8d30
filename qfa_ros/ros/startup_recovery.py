"""At start, recover in the background what an earlier run of the node left unfinished."""

import threading
import time

from qfa_ros.ros.bounds import confined_directory
from qfa_ros.ros.pacing import lower_thread_priority

RECOVERY_NICE = 19
"""Niceness added to the recovery thread (Linux; the kernel caps it at 19): the least of
the node's threads. A recovery may take long on a busy machine; the stream must not."""


class StartupRecovery:
    """
    Recover the recordings and traces an earlier run of this node left unfinished.

    A node killed (``kill -9``, the OOM killer, a power cut) leaves its bag directory with
    a ``.part`` file and an out-of-date ``metadata.yaml``, and a trace cut short as
    ``qfa_<kind>_<time>.mcap.part``. At start a thread of low priority looks for them, and
    only there: bag directories named ``<node name>_YYYY_MM_DD-HH_MM_SS[_N]`` in
    ``recorder.directory`` and trace parts in ``trace_dir``, both confined to
    ``output_dir`` (no symlink followed, bounded: :mod:`qfa_ros.bag.recovery`). Looking
    costs ``stat`` calls; what it finds it recovers as ``qfa-report recover`` does and
    names in one WARN line. A directory another live node records into is locked and left
    alone. Nothing waits for it: the node starts it once the first samples are out, and
    the thread yields the cores to the sensor and pacer threads.

    Parameters
    ----------
    node
        The node (its name: the recordings' prefix; its logger).
    values
        The node's parameter values at start.
    on_recovered : callable, optional
        Called with no argument, on the recovery thread, after it recovered a recording:
        a killed bag held retention back until now (the node's retention pass).
    """

    def __init__(self, node, values, on_recovered=None):
        self._node = node
        self._values = values
        self._on_recovered = on_recovered
        self._stop = threading.Event()
        # Protects _started: start and stop may come from two threads.
        self._starting = threading.Lock()
        self._started = False
        self._thread = threading.Thread(target=self._run, name='qfa_recovery', daemon=True)
        self.results = []
        """The :class:`~qfa_ros.bag.recovery.Recovery` of everything recovered (tests)."""
        self.done = threading.Event()
        self.completed = False
        """Whether it looked everywhere (not stopped half way, no error): nothing an earlier
        run left is left to find by this process (a managed node looks once)."""

    def start(self):
        """Start looking (and recovering) in the background; once, and not after ``stop``."""
        with self._starting:
            if not self._started and not self._stop.is_set():
                self._started = True
                self._thread.start()

    def stop(self, timeout_s=10.0):
        """
        Ask the thread to stop and wait at most ``timeout_s``.

        A recovery under way stops between two chunks before it changed anything, or
        finishes the file it is writing; either way the file stays recoverable.
        """
        with self._starting:
            self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def _yield(self):
        """
        Let the other threads run, then say whether to stop (between two chunks).

        Niceness does not govern the GIL: a Python loop keeps it up to the interpreter's
        switch interval (5 ms) while the pacer waits for it. Sleeping zero seconds hands it
        over at every chunk (about 0.1 ms of work).
        """
        time.sleep(0)
        return self._stop.is_set()

    def _run(self):
        lower_thread_priority(RECOVERY_NICE)
        logger = self._node.get_logger()
        try:
            # Imported here: the MCAP packages load only when there is something to recover.
            from qfa_ros.bag.recovery import (
                recover_bag_directory,
                recover_trace,
                unfinished_recordings,
                unfinished_traces,
            )
            recordings = unfinished_recordings(
                confined_directory(self._values, 'recorder.directory'), self._node.get_name())
            traces = unfinished_traces(confined_directory(self._values, 'trace_dir'))
            for path in recordings:
                self.results.append(recover_bag_directory(path, self._yield))
            for path in traces:
                self.results.append(recover_trace(path, self._yield))
            done = [result for result in self.results if result.status != 'in use']
            if done:
                logger.warning(
                    f'recovered {len(done)} recording(s) and trace(s) an earlier run left '
                    f'unfinished (killed or cut off; `qfa-report recover DIR` does the same): '
                    + '; '.join(result.describe() for result in done))
            self.completed = not self._stop.is_set()
            if recordings and self._on_recovered is not None and not self._stop.is_set():
                self._on_recovered()
        except Exception as error:  # a thread of the node never raises; it says why
            if not self._stop.is_set():
                logger.error(f'recovery of unfinished recordings at start failed: '
                             f'{type(error).__name__}: {error}')
        finally:
            self.done.set()
