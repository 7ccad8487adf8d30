"""Ground-truth input: specific force from a topic, held onto the sample grid."""

import math

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np

from qfa_ros.model.triad import NS_PER_S
from qfa_ros.ros.params import static_profile

MAX_PENDING_INPUTS = 10000


class GroundTruthInput:
    """
    Specific force from ``input/imu`` or ``input/accel`` (``input.mode: topic``).

    Inputs are queued in stamp order; each sample takes the latest input stamped at or
    before it (sample and hold) and is stale once that input is older than
    ``input.timeout_s``. Before the first input the static orientation stands in.
    The caller holds the node lock around every method.

    :param values: The node's live parameter values (read, never written).
    """

    def __init__(self, values):
        self._values = values
        self.pending = []
        self.held = None
        self.rejected = 0
        self.problem = None

    @property
    def active(self):
        """Return True when the input comes from the topic."""
        return self._values['input.mode'] == 'topic'

    def accept(self, time_ns, value):
        """Queue one input ``value`` (m/s^2, x y z) stamped ``time_ns``; refuse bad ones."""
        if not all(math.isfinite(v) for v in value):
            self.rejected += 1
            self.problem = f'non-finite ground-truth input rejected: {value}'
            return
        if self.pending and time_ns < self.pending[-1][0]:
            self.rejected += 1
            self.problem = 'ground-truth input out of order rejected'
            return
        self.pending.append((time_ns, value))
        if len(self.pending) > MAX_PENDING_INPUTS:
            # Inputs stamped ahead of the stream (another clock) must not pile up.
            self.held = self.pending.pop(0)

    def force(self, stamps):
        """Return (specific force per sample, stale mask) in topic mode, else (None, None)."""
        if not self.active:
            return None, None
        count = len(stamps)
        fallback = self.held
        if fallback is None:
            fallback = (None, tuple(static_profile(self._values).specific_force))
        if not self.pending:
            force = np.tile(fallback[1], (count, 1))
            times = np.full(count, -1 if fallback[0] is None else fallback[0], dtype=np.int64)
        else:
            times_in = np.array([t for t, _ in self.pending], dtype=np.int64)
            values_in = np.array([v for _, v in self.pending])
            index = np.searchsorted(times_in, stamps, side='right') - 1
            force = values_in[np.maximum(index, 0)]
            times = times_in[np.maximum(index, 0)]
            before = index < 0
            force[before] = fallback[1]
            times[before] = -1 if fallback[0] is None else fallback[0]
            last = int(index[-1])
            if last >= 0:
                # Keep the sample-and-hold value and every input not used yet.
                self.held = self.pending[last]
                del self.pending[:last + 1]
        timeout_ns = int(self._values['input.timeout_s'] * NS_PER_S)
        stale = (times < 0) | (stamps - times > timeout_ns)
        return force, stale

    def held_force(self, count):
        """Return the latest input repeated ``count`` times (topic mode), else None."""
        if not self.active:
            return None
        value = self.pending[-1][1] if self.pending else (
            self.held[1] if self.held else static_profile(self._values).specific_force)
        return np.tile(np.asarray(value, dtype=float), (count, 1))

    def status(self, now_ns):
        """Return ``(level, message, key values)`` for the ``input`` diagnostic."""
        mode = self._values['input.mode']
        values = [('mode', mode), ('rejected inputs', self.rejected)]
        if mode == 'profile':
            values.append(('profile', self._values['input.profile']))
        if mode != 'topic':
            return DiagnosticStatus.OK, mode, values
        latest = self.pending[-1] if self.pending else self.held
        level, message = DiagnosticStatus.OK, 'ground-truth topic'
        if latest is None:
            level, message = DiagnosticStatus.WARN, \
                'no ground-truth input yet: imu/data_raw paused'
        else:
            age = (now_ns - latest[0]) / 1e9
            values.append(('input age [s]', f'{age:.3f}'))
            if age > self._values['input.timeout_s']:
                level, message = DiagnosticStatus.WARN, \
                    f'ground-truth input stale ({age:.3f} s old): imu/data_raw paused'
        if self.problem:
            values.append(('last rejection', self.problem))
            if level == DiagnosticStatus.OK and self.rejected:
                level, message = DiagnosticStatus.WARN, \
                    f'ground-truth topic; {self.problem} (last value held)'
        return level, message, values
