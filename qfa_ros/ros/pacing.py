"""
Publish each computed message at its own instant, and record it off the publishing path.

The sensor thread (:mod:`qfa_ros.ros.stream`) computes the model ahead of the clock in
batches and hands the serialized messages to a :class:`Pacer`; the pacer's thread sleeps
until each message's stamp and publishes it then (never before), so a subscriber sees one
sample per sample period instead of a burst per batch. What it published goes to a
:class:`RecordingQueue` whose thread does the flight recorder's disk work (chunking,
compression, fsync) away from the publishing thread.
"""

import collections
import ctypes
import os
import platform
import threading
import time

SIM_POLL_S = 0.001
"""Wall-time poll period of the pacer while the node clock follows ``/clock`` [s]."""

MAX_SLEEP_S = 0.1
"""Longest single sleep of the pacer: it re-checks a stop or a cleared queue this often."""

LATE_NS = 5_000_000
"""A message published more than this after its stamp counts as late [ns]."""

STALE_NS = 1_000_000_000
"""A message still unpublished this long after its stamp is dropped, not published [ns].

The publishing side's :data:`~qfa_ros.ros.stream.MAX_CATCH_UP_S`: a pacer slower than the
stream would queue without end (``bench/results/soak_growth.md``). Not applied with
``use_sim_time``, whose samples are late, never lost."""

CATCH_UP_BURST = 3
"""Messages the pacer may publish back to back when it catches up after a stall."""

CATCH_UP_SPACING_NS = 150_000
"""Least time between publications beyond :data:`CATCH_UP_BURST` while catching up [ns].

A subscriber keeping the last 5 (``SensorDataQoS``) loses the oldest of a longer burst, so
a catch-up is a token bucket, slept, never spaced wider than the stamps (the variants
measured: ``bench/results/node_rate.md``, *How the catch-up was chosen*)."""

RECORD_PERIOD_S = 0.25
"""How often the recording thread writes what was published meanwhile [s].

Each write ends the chunk and fsyncs the file
(:meth:`~qfa_ros.ros.recording.StreamRecording.checkpoint`): a kill loses at most about a
period (``docs/node.md``, *Flight recorder*); longer runs cost less per message
(``bench/results/node_rate.md``, *Recording in runs*). Stopping or restarting the
recording writes what is queued first."""

IDLE_PERIOD_S = 1.0
"""How often the recording thread wakes while nothing is recorded [s]."""

BACKGROUND_NICE = 10
"""Niceness added to the threads that work ahead of or behind the pacer (Linux).

The sensor thread computes ``stream.lead_s`` ahead and the recording thread writes what
was published (at :data:`RECORDING_NICE`): neither has a deadline within a sample period,
the pacer has. On two busy cores the scheduler then lets the waking pacer take the core
from them at once, instead of after their time slice."""

RECORDING_NICE = 5
"""Niceness added to the recording thread (Linux): under the pacer's, over the sensor thread's.

Its deadline (the flight recorder's crash bound, ``docs/node.md``) is looser than the
pacer's, but at + 10 on a loaded machine it fell behind it
(``bench/results/crash_recording.md``, runs 1 and 2); + 5 triples its scheduler weight (335
against 110) and still lets the waking pacer take the core first."""


PACER_SLICE_NS = 100_000
"""Time slice the pacer thread asks the scheduler for [ns] (Linux 6.12+ EEVDF; 0.1 ms, the least).

EEVDF lets the running thread finish its slice before a thread it woke on the same CPU
runs, unless the woken one asked for a shorter slice: the sensor thread's batch no longer
holds the woken pacer up (``bench/results/node_rate.md``, *The pacer's time slice*). A
thread may shorten its own slice without privilege; older kernels keep the default."""

# --- sched_setattr(2) -----------------------------------------------------------------------
# Python's os module wraps sched_setscheduler and sched_setparam but not sched_setattr, the
# only call that sets a SCHED_OTHER thread's time slice, and glibc has no wrapper either: it
# is called through libc's syscall(). The two facts it needs, kept here and checked against
# the kernel ABI by test/test_node_delivery.py, are the call's number and its struct.

SCHED_SETATTR_NUMBERS = {
    'x86_64': 314,  # arch/x86/entry/syscalls/syscall_64.tbl
    'aarch64': 274,  # include/uapi/asm-generic/unistd.h (__NR_sched_setattr)
}
"""``sched_setattr`` system call number by ``platform.machine()``; elsewhere it is a no-op."""

SCHED_ATTR_SIZE_VER1 = 56
"""Size of version 1 of ``struct sched_attr`` (include/uapi/linux/sched.h) [bytes]."""


class SchedAttr(ctypes.Structure):
    """``struct sched_attr`` of include/uapi/linux/sched/types.h, version 1.

    Every field is naturally aligned, so the layout (and 56 bytes) is the same on every
    architecture, in the machine's byte order.
    """

    _fields_ = [
        ('size', ctypes.c_uint32),
        ('sched_policy', ctypes.c_uint32),
        ('sched_flags', ctypes.c_uint64),
        ('sched_nice', ctypes.c_int32),
        ('sched_priority', ctypes.c_uint32),
        ('sched_runtime', ctypes.c_uint64),
        ('sched_deadline', ctypes.c_uint64),
        ('sched_period', ctypes.c_uint64),
        ('sched_util_min', ctypes.c_uint32),
        ('sched_util_max', ctypes.c_uint32),
    ]


def sched_setattr(thread, attr, machine=None):
    """
    Call ``sched_setattr(thread, attr, 0)``; return True if the kernel accepted it.

    Parameters
    ----------
    thread
        Native thread id (0 is the calling thread).
    attr
        A :class:`SchedAttr`.
    machine
        ``platform.machine()`` by default; an architecture without a known call number (or a system
        other than Linux) makes this a no-op returning False.
    """
    machine = platform.machine() if machine is None else machine
    number = SCHED_SETATTR_NUMBERS.get(machine) if platform.system() == 'Linux' else None
    if number is None:
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
    except OSError:  # no libc to call through
        return False
    return libc.syscall(number, thread, ctypes.byref(attr), 0) == 0


def request_short_time_slice(slice_ns=PACER_SLICE_NS):
    """
    Ask the scheduler for a ``slice_ns`` time slice for the calling thread (Linux; else no-op).

    The thread keeps its policy (``SCHED_OTHER``) and niceness; the slice is what a
    ``SCHED_OTHER`` thread's ``sched_runtime`` means since Linux 6.12. Where the call is
    missing or refused the thread keeps the default slice, which costs latency only.
    Return True if the kernel accepted the request.
    """
    thread = threading.get_native_id()
    try:
        attr = SchedAttr(size=SCHED_ATTR_SIZE_VER1, sched_policy=os.SCHED_OTHER,
                         sched_nice=os.getpriority(os.PRIO_PROCESS, thread),
                         sched_runtime=slice_ns)
    except (AttributeError, OSError):  # not a POSIX system
        return False
    return sched_setattr(thread, attr)


def lower_thread_priority(nice=BACKGROUND_NICE):
    """
    Lower the calling thread's CPU priority by ``nice`` (Linux; else no-op).

    Raising one's own niceness needs no privilege; where it is refused the thread keeps
    its priority, which costs latency, not correctness.
    """
    thread = threading.get_native_id()
    try:
        os.setpriority(os.PRIO_PROCESS, thread,
                       os.getpriority(os.PRIO_PROCESS, thread) + nice)
    except (AttributeError, OSError):  # not Linux, or refused
        pass


class Pacer:
    """
    Publish serialized messages, each as soon as the node clock reaches its stamp.

    A message the pacer reaches more than :data:`STALE_NS` after its stamp is dropped
    (counted in :attr:`dropped`), so the messages waiting never span much more than a
    second, however long the thread was held up.

    Parameters
    ----------
    node
        The node (its clock: system time, or ``/clock`` with ``use_sim_time``).
    on_published
        Called on the pacer thread with ``(publisher, msgtype, data, time_ns)`` after each
        publication (the recording hook; before a :meth:`pause` returns, so it must not block), or
        None.
    on_empty
        Called on the pacer thread when it has published everything it was given (it asks the
        sensor thread for more), or None.
    on_started
        Called once on the pacer thread after the first messages it was given are published, or
        None.
    """

    def __init__(self, node, on_published=None, on_empty=None, on_started=None):
        self._node = node
        self._on_published = on_published
        self._on_empty = on_empty
        self._on_started = on_started
        # _condition protects _queue and _generation (sensor thread puts and clears, the
        # pacer thread takes); everything else is written by the pacer thread only.
        self._condition = threading.Condition()
        self._queue = collections.deque()
        self._generation = 0
        self._stop = False
        # _gate protects _paused and _publish_from_ns (nothing stamped earlier is
        # published); held around each publication and its recording hook, so that once
        # pause() returns nothing more is published and all that was is handed over.
        self._gate = threading.Lock()
        self._paused = False
        self._publish_from_ns = 0
        self.published = 0
        self.late = 0
        self.dropped = 0
        # Messages due while paused or stamped before the resumption: never published.
        self.unpublished = 0
        self.max_delay_ns = 0
        self.last_stamp_ns = None
        # The messages taken off the queue, being published (pacer thread only).
        self._hand, self._hand_index = (), 0
        # When the last publication ended, its stamp [ns] and the catch-up tokens left
        # (pacer thread only).
        self._previous = (0, 0, float(CATCH_UP_BURST))
        self._thread = threading.Thread(target=self._loop, name='qfa_pacer', daemon=True)

    def start(self):
        """Start the publishing thread."""
        self._thread.start()

    def stop(self, timeout_s=10.0):
        """Stop the publishing thread (messages stamped later are not published)."""
        with self._condition:
            self._stop = True
            self._condition.notify()
        if self._thread.is_alive():
            self._thread.join(timeout=timeout_s)

    def put(self, items):
        """
        Queue ``(stamp_ns, publisher, msgtype, data)`` items, in stamp order.

        Their stamps must not precede those already queued.
        """
        if not items:
            return
        with self._condition:
            self._queue.extend(items)
            self._condition.notify()

    def clear(self):
        """Forget every queued message (the clock went back: they will never be due)."""
        with self._condition:
            self._queue.clear()
            self._generation += 1
            self.last_stamp_ns = None

    def pause(self):
        """
        Publish nothing more; return once no publication is under way.

        Every message published before it returns has been given to ``on_published``.

        The queue is kept: each message is dropped when it comes due while paused, and one
        due after :meth:`resume` is published then (a quick reactivation loses none).
        """
        with self._gate:
            self._paused = True

    def resume(self, now_ns):
        """
        Publish again, each message stamped at or after the present; return it [ns].

        Parameters
        ----------
        now_ns
            The node clock [ns] (a callable), read under the gate: a message that came due while
            the caller waited for it was still dropped as paused, so the present is only known once
            no publication can be under way.
        """
        with self._gate:
            from_ns = now_ns()
            self._paused = False
            self._publish_from_ns = from_ns
        return from_ns

    @property
    def pending(self):
        """Return how many messages wait for their instant."""
        return len(self._queue) + len(self._hand) - self._hand_index

    # Pacer thread ------------------------------------------------------------------------
    def _loop(self):
        request_short_time_slice()
        clock = self._node.get_clock()
        while True:
            with self._condition:
                while not self._queue and not self._stop:
                    self._condition.wait()
                if self._stop:
                    return
                # Take every queued message at once: one lock round per batch, not per sample.
                self._hand, self._hand_index = list(self._queue), 0
                self._queue.clear()
                generation = self._generation
            self._publish_hand(clock, generation)
            self._hand, self._hand_index = (), 0
            if self._on_started is not None and self.published:
                on_started, self._on_started = self._on_started, None
                on_started()
            if self._on_empty is not None and not self._queue:
                self._on_empty()

    def _publish_hand(self, clock, generation):
        """Publish the messages in hand, each at its stamp, until done, cleared or stopped."""
        on_published = self._on_published
        # Read once per hand, not per sample (the property costs about as much as a
        # publication): the messages in hand were stamped on the clock of that moment.
        simulated = clock.ros_time_is_active
        wait = self._wait_until
        gate = self._gate
        previous, previous_stamp, tokens = self._previous
        for index, (stamp, publisher, msgtype, data) in enumerate(self._hand):
            self._hand_index = index
            now = wait(clock, stamp, generation, simulated)
            if now is None:
                return
            if now - stamp > STALE_NS and not simulated:
                # Held up for more than a second: the stream resumes at the present.
                self.dropped += 1
                self.last_stamp_ns = stamp
                continue
            # Catching up: a few back to back, then a stream, not a burst (a token per
            # spacing; never spaced wider than the stamps, so never slower than the stream).
            spacing = min(CATCH_UP_SPACING_NS, stamp - previous_stamp)
            if not simulated and spacing > 0:
                tokens = min(CATCH_UP_BURST, tokens + (now - previous) / spacing)
                if tokens < 1.0:
                    now = wait(clock, previous + int((1.0 - tokens) * spacing), generation,
                               False)
                    if now is None:
                        return
                    tokens = 1.0
                tokens -= 1.0
            with gate:
                dropped = self._paused or stamp < self._publish_from_ns
                if not dropped:
                    publisher.publish(data)
                    if on_published is not None:
                        # Under the gate: once pause() returns, every message published
                        # is in the recording's queue, and a deactivation's split puts it
                        # in its period's file (else the next period's file could begin
                        # with it: test_pause_returns_after_the_recording_hook).
                        on_published(publisher, msgtype, data, now)
            if dropped:
                # Due while paused (a managed node inactive): neither sent nor recorded.
                self.unpublished += 1
                continue
            # After the call: a stall inside it (the GIL, the CPU) counts as the gap.
            previous, previous_stamp = time.time_ns(), stamp
            self._previous = previous, stamp, tokens
            self.published += 1
            self.last_stamp_ns = stamp
            delay = now - stamp
            if delay > LATE_NS:
                self.late += 1
            if delay > self.max_delay_ns:
                self.max_delay_ns = delay

    def _wait_until(self, clock, stamp, generation, simulated):
        """
        Sleep until the node clock reaches ``stamp``; return the clock then [ns].

        Return None if the pacer was stopped or its queue cleared meanwhile.
        """
        while True:
            if self._stop or generation != self._generation:
                return None
            if simulated:
                now = clock.now().nanoseconds
                if now >= stamp:
                    return now
                time.sleep(SIM_POLL_S)
                # use_sim_time may have been switched off meanwhile.
                simulated = clock.ros_time_is_active
                continue
            # The node clock is the system clock (CLOCK_REALTIME, as time.time_ns) unless
            # use_sim_time made it follow /clock; time.time_ns costs far less than Clock.now.
            now = time.time_ns()
            if now >= stamp:
                return now
            time.sleep(min(stamp - now, MAX_SLEEP_S * 1e9) / 1e9)


class RecordingQueue:
    """
    Write what the pacer published into the flight recording, on a thread of its own.

    The pacer only appends to a queue; every ``RECORD_PERIOD_S`` this thread records the
    queued messages under the recording's own lock, never the node lock, so chunking,
    compression and a write the disk holds up delay neither a publication nor the sensor
    thread that feeds the pacer.

    Parameters
    ----------
    recording
        :class:`~qfa_ros.ros.recording.StreamRecording`.
    """

    def __init__(self, recording):
        self._recording = recording
        # deque.append and popleft are atomic: the pacer appends, the writer pops.
        self._queue = collections.deque()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name='qfa_recorder', daemon=True)

    def start(self):
        """Start the recording thread."""
        self._thread.start()

    def stop(self, timeout_s=10.0):
        """Stop the recording thread after it has recorded everything queued."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=timeout_s)
        self.flush()

    def append(self, publisher, msgtype, data, time_ns):
        """Queue one message ``publisher`` published (any thread; never blocks)."""
        if self._recording.active:
            self._queue.append((publisher, msgtype, data, time_ns))

    def flush(self):
        """Record every message queued so far (any thread)."""
        queue = self._queue
        topics = {}
        runs = []
        # Drained under the recording's lock: a restart waits for them to reach the file
        # they were published in.
        with self._recording.lock:
            previous = None
            while queue:
                publisher, msgtype, data, time_ns = queue.popleft()
                if publisher is not previous:
                    # A run of one topic is written with one call; the topic name is
                    # looked up here, off the publishing thread.
                    topic = topics.get(publisher)
                    if topic is None:
                        topic = topics[publisher] = publisher.topic_name
                    datas, times = [], []
                    runs.append((topic, msgtype, datas, times))
                    previous = publisher
                datas.append(data)
                times.append(time_ns)
            if runs:
                self._recording.record_runs(runs)

    def _loop(self):
        lower_thread_priority(RECORDING_NICE)
        # Without a recording nothing is queued: wake seldom (a recording started meanwhile
        # is written at most IDLE_PERIOD_S later; stop wakes the thread at once).
        while not self._stop.wait(RECORD_PERIOD_S if self._recording.active
                                  else IDLE_PERIOD_S):
            if self._queue:
                self.flush()
            if self._recording.active:
                # What the executor recorded too (diagnostics, truth), chunk and fsync.
                self._recording.checkpoint()
