"""One loop axis of the triad (words, gains, kernel state, noise stream) and the chunk runner."""

import functools

import numpy as np

from qfa_ros.model import kernel
from qfa_ros.model.constants import STANDARD_GRAVITY
from qfa_ros.model.design import design_controller, pendulum_matrices
from qfa_ros.model.hardware import counts_to_accel, loop_gains
from qfa_ros.model.parallel import ChainRun, start_chains

PARALLEL_MIN_STEPS = 20_000
"""Loop steps per axis from which :func:`start_axes` spreads the axes over threads."""
SLICE_STEPS = 20_000
"""Loop steps per time slice of an axis when the axes run on threads."""
BESIDE_SLICE_STEPS = 100_000
"""Loop steps' worth of samples per call of the work beside the axes (the gyros).

Five axis slices: that work costs ~1/20 of an axis a sample, so its calls can be fewer;
each still lasts less than an axis slice, so the last one adds no tail to the chunk."""


DRAW_BLOCK_STEPS = 1 << 18
"""Loop steps whose normals an axis draws at once (2 MiB a noise source)."""


class AxisLoop:
    """
    One axis: its controller, the DA words, drifted gains and the kernel state.

    The words the FPGA can change at run time are ``controller`` (k(D(z))),
    ``n_fpga`` (modulation amplitude), ``n_vref`` (DA0 reference word), the switch
    M1 of the constant current source, and the open/closed-loop state.
    """

    def __init__(self, config, noise, axis):
        hw = config.hardware
        self.hw = hw
        self.config = config
        self.controller = design_controller(hw, config.loop_rate_hz, config.crossover_hz,
                                            config.integrator_ratio, config.lead_pole_ratio)
        self.n_fpga = hw.n_fpga
        self.n_vref = hw.n_vref
        self.reference_current_on = False
        self.open_loop = False
        self.held_command = 0
        self.gains = None
        self.params_f = np.zeros(kernel.N_FLOAT_PARAMS)
        self.params_i = np.zeros(kernel.N_INT_PARAMS, dtype=np.int64)
        self.state_f = np.zeros(kernel.N_FLOAT_STATE)
        self.state_i = np.zeros(kernel.N_INT_STATE, dtype=np.int64)
        ad, bd = pendulum_matrices(hw, 1.0 / config.loop_rate_hz)
        self.params_f[kernel.P_AD00:kernel.P_AD11 + 1] = ad.ravel()
        self.params_f[kernel.P_BD0:kernel.P_BD1 + 1] = bd
        self.params_f[kernel.P_PENDULOSITY] = hw.pendulosity
        self.params_f[kernel.P_STOP] = hw.stop_angle
        self.params_f[kernel.P_ADSORPTION] = hw.adsorption_g * STANDARD_GRAVITY * hw.pendulosity
        self.params_i[kernel.Q_DA2_FULL_SCALE] = hw.da2_full_scale
        self.params_i[kernel.Q_ADC_FULL_SCALE] = hw.adc_full_scale
        self.params_i[kernel.Q_RANGE_COUNTS] = int(
            hw.input_range_g * STANDARD_GRAVITY / counts_to_accel(hw))
        self.attach_noise(noise, axis)

    def attach_noise(self, noise, axis):
        """Draw this axis's noise from ``noise`` (a :class:`NoiseSource`), stream ``axis``."""
        self.params_f[kernel.P_WHITE_STD] = noise.white_std
        self.params_f[kernel.P_ADC_STD] = noise.adc_std
        self.rng = noise.streams[axis]
        self.gm_phi = noise.phi
        self.gm_drive = noise.drive_std
        self.gm_state = noise.bias_state[axis]  # a view: the source sees the state move
        self.params_i[kernel.Q_GM_BLOCK] = noise.gm_block
        self.state_i[kernel.T_GM_LEFT] = 0  # the new processes step at the next sample

    def update(self, drift):
        """Recompute the kernel parameters for the relative ``drift`` of each component."""
        self.gains = loop_gains(self.hw, drift, self.n_fpga, self.n_vref,
                                self.config.open_loop_cref_sensitivity)
        self.params_f[kernel.P_K_SENSE] = self.gains.k_sense
        self.params_f[kernel.P_OPEN_LOOP_COUNTS] = \
            self.gains.open_loop_counts_per_fpga * self.n_fpga
        self.params_f[kernel.P_K_FB] = self.gains.feedback_gain
        self.params_f[kernel.P_REF_MOMENT] = \
            self.gains.k_t * self.gains.i_ref if self.reference_current_on else 0.0
        c = self.controller
        self.params_i[kernel.Q_GAIN:kernel.Q_KI + 1] = (
            c.gain_word, c.lead_a1, c.lead_b0, c.lead_b1, c.integrator_gain)
        self.params_i[kernel.Q_OPEN_LOOP] = 1 if self.open_loop else 0

    def close(self):
        """Re-close the loop bumplessly: the integrator resumes the last closed-loop command."""
        held = self.held_command
        self.state_i[kernel.T_APPLIED] = held
        self.state_i[kernel.T_X_PREV] = 0
        self.state_i[kernel.T_Y_PREV] = 0
        self.state_i[kernel.T_INTEGRATOR] = held << 28
        self.open_loop = False

    def open(self):
        """Open the loop: feedback current off, the pendulum latches on its stop."""
        self.held_command = int(self.state_i[kernel.T_LAST])
        self.open_loop = True

    def run(self, sensed, scale, offset, decimation, out_mean, out_flags):
        """
        Run the compiled kernel, noise included, over one chunk (:func:`kernel.run_axis`).

        The stream's normals are drawn for at most ``DRAW_BLOCK_STEPS`` loop steps at a
        time (the kernel runs block after block), so a long chunk costs no more memory.
        """
        n_samples = len(out_mean)
        block = max(1, DRAW_BLOCK_STEPS // decimation)
        per_step = len(sensed) == n_samples * decimation and decimation > 1
        for a in range(0, n_samples, block):
            b = min(a + block, n_samples)
            normals = self.rng.standard_normal(kernel.axis_draws(
                b - a, decimation, self.params_f, self.params_i, self.state_i,
                len(self.gm_phi)))
            drawn = kernel.run_axis(
                normals, _part(sensed, a, b, decimation if per_step else 1),
                _part(scale, a, b), _part(offset, a, b), self.gm_phi, self.gm_drive,
                self.gm_state, decimation, self.params_f, self.params_i, self.state_f,
                self.state_i, out_mean[a:b], out_flags[a:b])
            if drawn != len(normals):
                raise RuntimeError(f'the loop kernel read {drawn} normals of {len(normals)}')


def _part(values, first, end, per_sample=1):
    # Samples first..end-1 of a chunk input: one value for the chunk, or ``per_sample``
    # values a sample.
    return values if len(values) == 1 else values[first * per_sample:end * per_sample]


def start_axes(loops, sensed, scale, offset, decimation, counts, flags, workers, beside=()):
    """
    Start the kernel of every axis over one chunk, in turn or as time slices on threads.

    Each axis draws from its own stream and its slices run in order, so the output is
    identical whatever ``workers`` is. Threads are used from ``PARALLEL_MIN_STEPS`` loop
    steps per axis on, with slices of about ``SLICE_STEPS`` steps (a call costs ~1 ms).

    Parameters
    ----------
    loops : sequence of AxisLoop
        The axes.
    sensed : float64[n_axes, m]
        Sensed specific force per axis [m/s^2], ``m`` = 1, ``n_samples`` or
        ``n_samples * decimation`` (see :func:`kernel.run_axis`).
    scale, offset : float64[n_axes, 1] or float64[n_axes, n_samples]
        Thermal scale factor [1] and zero bias [m/s^2].
    decimation : int
        Loop steps per sample.
    counts : float64[n_axes, n_samples]
        Mean output word per sample [count], written.
    flags : int8[n_axes, n_samples]
        Saturation bits per sample, written.
    workers : int
        Threads that may run axes at once (1: the calling thread only).
    beside : sequence of callables
        Independent GIL-free work over the same samples (the gyro triad): ``call(a, b)``
        does samples ``a..b-1``; run as a chain of slices of ``BESIDE_SLICE_STEPS``
        beside them on the threads, or once over the chunk after them.

    Returns
    -------
    qfa_ros.model.parallel.ChainRun
        Its ``join()`` returns when every output is written (at once when run in turn).
    """
    n_samples = counts.shape[1]
    threaded = workers > 1 and n_samples * decimation >= PARALLEL_MIN_STEPS
    if not threaded:
        for i, loop in enumerate(loops):
            loop.run(sensed[i], scale[i], offset[i], decimation, counts[i], flags[i])
        for call in beside:
            call(0, n_samples)
        return ChainRun(())
    step_input = sensed.shape[1] == n_samples * decimation and decimation > 1
    per_sample = decimation if step_input else 1

    def slices(steps):
        # (first, end) samples of consecutive slices of about ``steps`` loop steps.
        size = max(1, steps // decimation)
        return [(a, min(a + size, n_samples)) for a in range(0, n_samples, size)]

    bounds = slices(SLICE_STEPS)
    chains = [[functools.partial(loop.run, _part(sensed[i], a, b, per_sample),
                                 _part(scale[i], a, b), _part(offset[i], a, b),
                                 decimation, counts[i, a:b], flags[i, a:b])
               for a, b in bounds] for i, loop in enumerate(loops)]
    chains += [[functools.partial(call, a, b) for a, b in slices(BESIDE_SLICE_STEPS)]
               for call in beside]
    return start_chains(chains, workers)
