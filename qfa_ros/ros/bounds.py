"""
What a stray participant cannot exceed: the schedule ranges, their worst case, the write area.

ROS 2 without DDS Security lets any participant on the domain set parameters and call
services. The ranges below bound what one schedule call can cost (sensor time, during
which ``imu/data_raw`` is withheld, and model loop steps, i.e. CPU time), and
:func:`confined_directory` keeps every runtime-chosen directory under ``output_dir``.
"""

import os
from pathlib import Path

from qfa_ros.calibration.estimation import FeedbackSettings, ForwardSettings
from qfa_ros.calibration.temperature import TemperatureSettings
from qfa_ros.model.triad import TriadConfig

# Ranges of the schedule parameters. They bound what one service call can cost, whoever
# makes it: the sensor time it takes (imu/data_raw is withheld meanwhile) and the model
# loop steps it computes (its CPU time). SCHEDULE_WORST_S is the sensor time of the
# longest call the ranges allow (capture_reference or self_calibrate: a bidirectional
# forward sweep, then a chopped feedback schedule, each at its longest).
FORWARD_MAX_POINTS = 50
FORWARD_MAX_SETTLE_S = 0.5
FORWARD_MAX_AVERAGE_S = 2.0
FEEDBACK_MAX_CYCLES = 8
FEEDBACK_MAX_SETTLE_S = 0.5
FEEDBACK_MAX_AVERAGE_S = 20.0
CHAMBER_MAX_PERIOD_S = 4500.0
CHAMBER_MAX_CYCLES = 1
MAX_SCHEDULE_LOOP_STEPS = 144_000_000
"""Model loop steps one call may compute: 14400 s of sensor time at the default 10 kHz loop."""
SETTLE_TIME_S = TriadConfig.settle_time
"""Settling of the re-closed loops that ends every estimation schedule [s]."""


def forward_sensor_time_s(settings, settle_time_s):
    """Return the sensor time of one forward schedule [s] (sweep plus the loops' settling)."""
    return len(settings.sequence()) * (settings.settle_s + settings.average_s) + settle_time_s


def feedback_sensor_time_s(settings, settle_time_s):
    """Return the sensor time of one feedback schedule [s] (segments plus the settling)."""
    return (len(settings.sequence()) * (settings.settle_s + settings.average_s)
            + settings.settle_s + settle_time_s)


FORWARD_WORST_S = forward_sensor_time_s(
    ForwardSettings(points=FORWARD_MAX_POINTS, settle_s=FORWARD_MAX_SETTLE_S,
                    average_s=FORWARD_MAX_AVERAGE_S, order='bidirectional'), SETTLE_TIME_S)
FEEDBACK_WORST_S = feedback_sensor_time_s(
    FeedbackSettings(cycles=FEEDBACK_MAX_CYCLES, settle_s=FEEDBACK_MAX_SETTLE_S,
                     average_s=FEEDBACK_MAX_AVERAGE_S, order='chopped'), SETTLE_TIME_S)
SCHEDULE_WORST_S = FORWARD_WORST_S + FEEDBACK_WORST_S
"""Longest sensor time of an estimation call the ranges allow [s]."""
CHAMBER_WORST_S = TemperatureSettings(period_s=CHAMBER_MAX_PERIOD_S, cycles=CHAMBER_MAX_CYCLES,
                                      reference_steps=True).max_sensor_time_s()
"""Longest sensor time of a calibrate_temperature call the ranges allow [s]."""

ESTIMATION_BOUND = (
    f'; bounded: one call takes at most {SCHEDULE_WORST_S:.0f} s of sensor time '
    f'(capture_reference, self_calibrate; forward alone {FORWARD_WORST_S:.0f} s, feedback '
    f'alone {FEEDBACK_WORST_S:.0f} s) and at most {MAX_SCHEDULE_LOOP_STEPS:.3g} model loop '
    'steps')
CHAMBER_BOUND = (
    f'; bounded: one call takes at most {CHAMBER_WORST_S:.0f} s of sensor time and '
    f'{MAX_SCHEDULE_LOOP_STEPS:.3g} model loop steps (the plateaus of cycles x period_s, '
    'the soaks at the extremes and back, the I_ref steps at every plateau, times '
    'loop_rate_hz)')


def output_directory(values):
    """Return the resolved ``output_dir``: ``~`` expanded, symlinks and ``..`` resolved."""
    return Path(os.path.expanduser(values['output_dir'])).resolve()


def confined_directory(values, name):
    """
    Return the resolved directory of parameter ``name``, confined to ``output_dir``.

    A relative value is taken under ``output_dir``; an absolute one must resolve inside
    it. Symlinks and ``..`` are resolved (as far as the path exists) before the
    comparison, so neither leads out. ``~`` is not expanded: a value starting with it
    is refused rather than taken literally. Resolve again right before writing: a
    symlink may have been swapped since the parameter was checked.

    :raises ValueError: The directory would lie outside ``output_dir``; the message
        names the parameter.
    """
    value = values[name]
    if not value:
        raise ValueError(f'{name} must not be empty')
    if value.startswith('~'):
        raise ValueError(f'{name} {value!r}: ~ is not expanded; give a path relative to '
                         f'output_dir or an absolute path inside it')
    base = output_directory(values)
    directory = (base / value).resolve()
    if directory != base and base not in directory.parents:
        raise ValueError(f'{name} {value!r} resolves to {directory}, outside output_dir '
                         f'{base}: the node writes only under output_dir (read-only, chosen '
                         f'at start)')
    return directory


def budget_problem(loop_rate_hz, forward, feedback, chamber):
    """
    Return why one schedule call would compute too many model loop steps, or None.

    :param loop_rate_hz: The model's loop rate [Hz].
    :param forward, feedback: :class:`ForwardSettings`, :class:`FeedbackSettings`.
    :param chamber: :class:`~qfa_ros.calibration.temperature.TemperatureSettings`.
    """
    estimation = (forward_sensor_time_s(forward, SETTLE_TIME_S)
                  + feedback_sensor_time_s(feedback, SETTLE_TIME_S))
    if estimation * loop_rate_hz > MAX_SCHEDULE_LOOP_STEPS:
        return (f'estimation.forward.* / estimation.feedback.*: one capture_reference would '
                f'take {estimation:.0f} s of sensor time, {estimation * loop_rate_hz:.3g} loop '
                f'steps at loop_rate_hz {loop_rate_hz:g}; at most '
                f'{MAX_SCHEDULE_LOOP_STEPS:.3g} are allowed')
    chamber_s = chamber.max_sensor_time_s()
    if chamber_s * loop_rate_hz > MAX_SCHEDULE_LOOP_STEPS:
        return (f'temperature_calibration.period_s x temperature_calibration.cycles: one '
                f'calibrate_temperature would take {chamber_s:.0f} s of sensor time, '
                f'{chamber_s * loop_rate_hz:.3g} loop steps at loop_rate_hz '
                f'{loop_rate_hz:g}; at most {MAX_SCHEDULE_LOOP_STEPS:.3g} are allowed')
    return None
