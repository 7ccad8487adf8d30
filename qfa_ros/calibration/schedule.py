"""
What every schedule shares: its error, the sensor time, and the offline driver.

A schedule is a generator that drives the loop words of a :class:`QfaTriad`, yields how
many samples it needs next, and receives them as one :class:`TriadOutput`; it returns
its result. :func:`run_schedule` drives one offline as fast as the CPU allows; the node
drives the same generators paced by the ROS clock.
"""

from qfa_ros.model.triad import concatenate


class EstimationError(ValueError):
    """A schedule cannot run or its data cannot give an estimate; nothing was applied."""


def samples_for(triad, seconds):
    """Return how many samples (at least one) span ``seconds`` of sensor time."""
    return max(1, int(round(seconds * triad.config.sample_rate_hz)))


def sensor_time_ns(triad):
    """Return the sensor time of the next sample [ns]."""
    return int(triad.sample_index * 1e9 / triad.config.sample_rate_hz)


def require_closed(triad):
    """Raise :class:`EstimationError` if a loop is open (another schedule runs)."""
    if any(loop.open_loop for loop in triad.axes):
        raise EstimationError('a loop is open: another schedule is running')


def run_schedule(triad, schedule, chunk_samples=1000, progress=None):
    """
    Drive a schedule generator offline, as fast as possible; return its result.

    The generator yields how many samples it needs; the driver runs the triad for that
    many (in chunks of at most ``chunk_samples``) and sends back the output.
    ``progress``, if given, is called with the sensor seconds of every chunk run.
    """
    try:
        request = next(schedule)
        while True:
            parts = []
            remaining = request
            while remaining > 0:
                n = min(chunk_samples, remaining)
                parts.append(triad.run(n))
                remaining -= n
                if progress is not None:
                    progress(n / triad.config.sample_rate_hz)
            request = schedule.send(concatenate(parts))
    except StopIteration as stop:
        return stop.value
