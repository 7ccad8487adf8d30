"""
What a stray participant cannot exceed: the schedule ranges, their worst case, the write area.

ROS 2 without DDS Security lets any participant on the domain set parameters and call
services. The ranges below bound what one schedule call can cost (sensor time, during
which ``imu/data_raw`` is withheld, and model loop steps, i.e. CPU time), and
:func:`confined_directory` keeps every runtime-chosen directory under ``output_dir``. Each
service's worst case and the budget check over every schedule are the services table's
(:mod:`qfa_ros.ros.service_table`).
"""

import math
import os
from pathlib import Path

from qfa_ros.calibration.estimation import (
    feedback_sensor_time_s,
    FeedbackSettings,
    forward_sensor_time_s,
    ForwardSettings,
)
from qfa_ros.calibration.temperature import TemperatureSettings
from qfa_ros.model.constants import PPM
from qfa_ros.model.hardware import AxisHardware, nominal_gains
from qfa_ros.model.triad_config import TriadConfig

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
MAX_SCHEDULE_LOOP_STEPS = 180_000_000
"""Model loop steps one call may compute: 18000 s of sensor time at the default 10 kHz loop."""
CHAMBER_MAX_SENSOR_S = 18_000.0
"""Sensor time one calibrate_temperature call may take [s], whatever the loop rate and the
ambient: the default chamber limits at the longest period take 16 877 s from an ambient at
``high_c``. The ranges alone do not bound it tightly: fewer plateaus (``low_c`` and
``high_c`` close together, or an ambient near ``high_c``) hold longer each, and the turning
points soak up to ten holds, so the settings are checked as a whole
(:meth:`TemperatureSettings.max_sensor_time_s`)."""
SETTLE_TIME_S = TriadConfig.settle_time
"""Settling of the re-closed loops that ends every estimation schedule [s]."""


FORWARD_HEADROOM = 1.05
"""Open-loop output margin under the ADC full scale at the forward sweep's top word: the
chain's thermal and aging gain changes (a few 1000 ppm) and 5 % more do not clip it."""


def forward_max_span(hardware, gain_factor=1.0):
    """
    Return the largest forward sweep span ``points x step`` [count] ``hardware`` takes.

    The sweep writes up to ``N_FPGA + points step`` to DA1; that word must stay under
    DA1's full scale and its open-loop output (``open_loop_counts_per_fpga`` per word,
    times ``gain_factor`` for a known forward drift, times :data:`FORWARD_HEADROOM`)
    under the ADC's.
    """
    counts_per_word = nominal_gains(hardware).open_loop_counts_per_fpga
    adc_word = 2 ** (hardware.n_ad_bits - 1) / (counts_per_word * gain_factor
                                                * FORWARD_HEADROOM)
    top_word = min(2 ** (hardware.n_da1_bits - 1) - 1, math.floor(adc_word))
    return max(0, top_word - int(hardware.n_fpga))


FORWARD_MAX_SPAN = forward_max_span(AxisHardware())
"""Largest ``estimation.forward.points x step`` of the nominal hardware [count]."""


def forward_sweep_problem(settings, hardware, forward_drift_ppm=(0.0,)):
    """
    Return why the forward sweep of ``settings`` would leave DA1's or the ADC's range.

    Parameters
    ----------
    settings
        :class:`ForwardSettings`.
    hardware
        The axes' :class:`~qfa_ros.model.hardware.AxisHardware`.
    forward_drift_ppm
        Injected forward-gain drift per axis [ppm]; the largest raises the open-loop output.
    """
    gain_factor = 1.0 + max(0.0, max(forward_drift_ppm)) * PPM
    span = forward_max_span(hardware, gain_factor)
    if settings.points * settings.step <= span:
        return None
    return (f'estimation.forward.points x estimation.forward.step = '
            f'{settings.points} x {settings.step} = {settings.points * settings.step} '
            f'counts: the sweep would drive DA1 or the ADC out of range; at most {span} '
            f'(N_FPGA {hardware.n_fpga} + the span stays under the ADC full scale with '
            f'{FORWARD_HEADROOM - 1:.0%} headroom; a positive drift.forward_ppm raises the '
            f'open-loop output and narrows it)')


LARGEST_FORWARD = ForwardSettings(points=FORWARD_MAX_POINTS,
                                  step=FORWARD_MAX_SPAN // FORWARD_MAX_POINTS,
                                  settle_s=FORWARD_MAX_SETTLE_S,
                                  average_s=FORWARD_MAX_AVERAGE_S, order='bidirectional')
"""The longest forward sweep the parameter ranges allow."""
LARGEST_FEEDBACK = FeedbackSettings(cycles=FEEDBACK_MAX_CYCLES, settle_s=FEEDBACK_MAX_SETTLE_S,
                                    average_s=FEEDBACK_MAX_AVERAGE_S, order='chopped')
"""The longest I_ref schedule the parameter ranges allow."""
LARGEST_CHAMBER = TemperatureSettings(period_s=CHAMBER_MAX_PERIOD_S, cycles=CHAMBER_MAX_CYCLES,
                                      reference_steps=True)
"""The longest calibrate_temperature program the parameter ranges allow at the default
chamber limits (other limits may take longer, up to :data:`CHAMBER_WORST_S`)."""
FORWARD_WORST_S = forward_sensor_time_s(LARGEST_FORWARD, SETTLE_TIME_S)
FEEDBACK_WORST_S = feedback_sensor_time_s(LARGEST_FEEDBACK, SETTLE_TIME_S)
SCHEDULE_WORST_S = FORWARD_WORST_S + FEEDBACK_WORST_S
"""Longest sensor time of an estimation call the ranges allow [s]."""
CHAMBER_WORST_S = CHAMBER_MAX_SENSOR_S
"""Longest sensor time of a calibrate_temperature call the settings allow [s]."""

FORWARD_SPAN_BOUND = (
    f'; points x step at most {FORWARD_MAX_SPAN} counts (DA1 and ADC range of the sweep)')
ESTIMATION_BOUND = (
    f'; bounded: one call takes at most {SCHEDULE_WORST_S:.0f} s of sensor time '
    f'(capture_reference, self_calibrate; forward alone {FORWARD_WORST_S:.0f} s, feedback '
    f'alone {FEEDBACK_WORST_S:.0f} s) and at most {MAX_SCHEDULE_LOOP_STEPS:.3g} model loop '
    'steps')
CHAMBER_BOUND = (
    f'; bounded: one call takes at most {CHAMBER_WORST_S:.0f} s of sensor time and '
    f'{MAX_SCHEDULE_LOOP_STEPS:.3g} model loop steps (the plateaus of cycles x period_s '
    'between low_c and high_c, the soaks at the turning points and back, the I_ref steps at '
    'every plateau, times loop_rate_hz)')


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

    Raises
    ------
    ValueError
        The directory would lie outside ``output_dir``; the message names the parameter.
    """
    value = values[name]
    rule = (f'{name} must name a directory inside output_dir: relative to it, or absolute '
            'inside it, symlinks and .. resolved (the node writes only under output_dir, '
            'read-only, chosen at start)')
    if not value:
        raise ValueError(f'{name} must not be empty')
    if value.startswith('~'):
        raise ValueError(f'{rule}; ~ is not expanded')
    base = output_directory(values)
    try:
        directory = (base / value).resolve()
    except (OSError, RuntimeError):
        # A symlink loop or an unreadable component; the error's text names the path.
        raise ValueError(f'{rule}; this one cannot be resolved') from None
    if directory != base and base not in directory.parents:
        # Never where it leads: /proc/self/cwd, /proc/<pid>/cwd, /proc/self/fd/N or a
        # link planted under output_dir would tell the caller paths it cannot see.
        raise ValueError(f'{rule}; this one leads outside it')
    return directory
