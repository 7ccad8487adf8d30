"""Compiled per-step kernel of one digital closed-loop QFA axis (numba, over chunks).

The noise of the axis comes as the standard normals its stream drew for the chunk
(:func:`axis_draws` of them, read in the kernel's order), not as the
``numpy.random.Generator`` itself: numba 0.58-0.60 (Ubuntu 24.04's) keeps ~585 bytes at
every call that unboxes a Generator (numba issue 9103), ~100 MiB an hour of a streaming
node. Drawn by numpy in the kernel's order, the numbers are the ones the Generator would
have given inside the loop, so a run split into chunks still draws what one long run
does. The input arrives at the rate it changes: one value per chunk, per sample or per
loop step.
"""

from numba import njit
import numpy as np

# Float parameter vector layout.
P_AD00, P_AD01, P_AD10, P_AD11, P_BD0, P_BD1 = range(6)
P_PENDULOSITY = 6        # K0 [kg m]
P_K_SENSE = 7            # closed-loop pick-off chain [count/rad]
P_OPEN_LOOP_COUNTS = 8   # open-loop ADC level (eq. 16) [count]
P_K_FB = 9               # k_DA2 k_VI k_t [N m/count]
P_REF_MOMENT = 10        # k_t I_ref while the switch M1 is closed, else 0 [N m]
P_STOP = 11              # stop angle [rad]
P_ADSORPTION = 12        # open-loop latching moment [N m]
P_WHITE_STD = 13         # white acceleration noise per loop step, std [m/s^2]
P_ADC_STD = 14           # ADC input noise per loop step, std [count]
N_FLOAT_PARAMS = 15

# Integer parameter vector layout.
Q_GAIN, Q_A1, Q_B0, Q_B1, Q_KI = range(5)
Q_OPEN_LOOP = 5          # 1: feedback off, pendulum latched, output = k(D(z)) e
Q_DA2_FULL_SCALE = 6     # [count]
Q_ADC_FULL_SCALE = 7     # [count]
Q_RANGE_COUNTS = 8       # rated range in command counts
Q_GM_BLOCK = 9           # samples per Gauss-Markov step (the bias instability holds)
N_INT_PARAMS = 10

# Float state: pendulum angle [rad] and rate [rad/s].
S_THETA, S_OMEGA = range(2)
N_FLOAT_STATE = 2

# Integer state: controller memories and the DA2 word on the torquer.
T_X_PREV, T_Y_PREV, T_INTEGRATOR, T_APPLIED, T_LAST = range(5)
T_GM_LEFT = 5            # samples the present Gauss-Markov value still holds
N_INT_STATE = 6

_GAIN_SHIFT = 24         # Q32 gain * count -> Q8 signal
_COEF_SHIFT = 20         # Q20 coefficients
_SIGNAL_SHIFT = 8        # Q8 signal -> count


@njit(cache=True, nogil=True)
def sense(force, misalignment, bias, k2, out):
    """
    Write the specific force each axis senses, ``out[i, k]`` [m/s^2].

    ``a = M f_k`` (``misalignment`` M (3, 3), the sensing axes in the body frame, applied
    to ``force`` f (n, 3) [m/s^2]), then ``out[i, k] = bias_i + a_i + k2_i a_i^2`` with
    ``bias`` [m/s^2] and ``k2`` [1/(m/s^2)] per axis: the input of :func:`run_axis`.
    """
    for k in range(force.shape[0]):
        f0, f1, f2 = force[k, 0], force[k, 1], force[k, 2]
        for i in range(3):
            a = misalignment[i, 0] * f0 + misalignment[i, 1] * f1 + misalignment[i, 2] * f2
            out[i, k] = bias[i] + a + k2[i] * a * a


@njit(cache=True, nogil=True)
def _round_shift(value, shift):
    # Round to nearest (ties up), as a hardware adder before an arithmetic shift does.
    return (value + (np.int64(1) << (shift - 1))) >> shift


def axis_draws(n_samples, decimation, params_f, params_i, state_i, n_components):
    """
    Return how many standard normals :func:`run_axis` reads over ``n_samples`` samples.

    ``n_components`` per Gauss-Markov step (one at each sample where the held value runs
    out: the first after ``state_i[T_GM_LEFT]`` samples, then every ``Q_GM_BLOCK``), and
    per loop step one for the white noise and one for the ADC where their std is not 0.
    """
    per_step = int(params_f[P_WHITE_STD] > 0.0) + int(params_f[P_ADC_STD] > 0.0)
    gm_steps = len(range(max(int(state_i[T_GM_LEFT]), 0), n_samples,
                         int(params_i[Q_GM_BLOCK]))) if n_components else 0
    return gm_steps * n_components + n_samples * decimation * per_step


@njit(cache=True, nogil=True)
def run_axis(normals, sensed, scale, offset, gm_phi, gm_drive, gm_state, decimation,
             params_f, params_i, state_f, state_i, out_mean, out_flags):
    r"""
    Advance one axis over a chunk of ``n = len(out_mean) * decimation`` loop steps.

    The loop input at step ``i`` of sample ``j`` is
    ``a_i = s_i c_j + o_j + sum_k b_k[j] + sigma_w w_i`` [m/s^2]: ``s`` the sensed
    specific force (model-equation terms included), ``c`` and ``o`` the thermal
    scale (1 + e(T)) and zero bias, ``b_k`` the first-order Gauss-Markov processes of
    the bias instability, ``b_k = phi_k b_k + q_k v_k`` once every ``Q_GM_BLOCK``
    samples and held in between (``phi_k``, ``q_k`` for that step), and ``w_i`` white.
    The ADC adds ``sigma_adc n_i`` [count]. ``v``, ``w`` and ``n`` are read from
    ``normals`` in a fixed order (at a Gauss-Markov step, before its sample: the drives;
    per step: ``w`` then ``n``; a source whose std is 0 reads nothing), so the output
    depends on the stream's seed, not on the chunk lengths.

    Returns the count of normals read (:func:`axis_draws`).

    Parameters
    ----------
    normals : float64[axis_draws(...)]
        Standard normal draws of this axis's stream, in the order above.
    sensed : float64[1], float64[n // decimation] or float64[n]
        Sensed specific force ``s`` [m/s^2]: constant over the chunk, per sample or
        per loop step (the latter only when its length is ``n`` and ``decimation > 1``).
    scale, offset : float64[1] or float64[n // decimation]
        Thermal scale factor ``c`` [1] and zero bias ``o`` [m/s^2], constant or per sample.
    gm_phi, gm_drive, gm_state : float64[k]
        Gauss-Markov ``phi_k``, drive std ``q_k`` [m/s^2] and state (updated in place);
        ``k = 0`` without bias instability.
    decimation : int
        Loop steps per output sample.
    params_f, params_i : float64[N_FLOAT_PARAMS], int64[N_INT_PARAMS]
        Loop and noise parameters (layout constants above).
    state_f, state_i : float64[N_FLOAT_STATE], int64[N_INT_STATE]
        Loop state, updated in place.
    out_mean : float64[n // decimation]
        Mean sensor output word per sample [count]: the DA2 command in closed loop,
        ``k(D(z)) e`` with its 8 fraction bits in open loop.
    out_flags : int8[n // decimation]
        Bit 0: DA2 command clipped; bit 1: ADC clipped; bit 2: over the rated range.
    """
    ad00 = params_f[P_AD00]
    ad01 = params_f[P_AD01]
    ad10 = params_f[P_AD10]
    ad11 = params_f[P_AD11]
    bd0 = params_f[P_BD0]
    bd1 = params_f[P_BD1]
    k0 = params_f[P_PENDULOSITY]
    k_sense = params_f[P_K_SENSE]
    open_counts = params_f[P_OPEN_LOOP_COUNTS]
    k_fb = params_f[P_K_FB]
    ref_moment = params_f[P_REF_MOMENT]
    stop = params_f[P_STOP]
    adsorption = params_f[P_ADSORPTION]
    white_std = params_f[P_WHITE_STD]
    adc_std = params_f[P_ADC_STD]
    gain = params_i[Q_GAIN]
    a1 = params_i[Q_A1]
    b0 = params_i[Q_B0]
    b1 = params_i[Q_B1]
    ki = params_i[Q_KI]
    open_loop = params_i[Q_OPEN_LOOP] != 0
    da2_fs = params_i[Q_DA2_FULL_SCALE]
    adc_fs = params_i[Q_ADC_FULL_SCALE]
    range_counts = params_i[Q_RANGE_COUNTS]
    gm_block = params_i[Q_GM_BLOCK]
    integrator_limit = (da2_fs << _SIGNAL_SHIFT) << _COEF_SHIFT
    draw_white = white_std > 0.0
    draw_adc = adc_std > 0.0
    n_components = gm_phi.shape[0]
    if open_loop:
        bias_moment = -ref_moment + adsorption
        sense = 0.0
        level = open_counts
    else:
        bias_moment = -ref_moment
        sense = k_sense
        level = 0.0

    theta = state_f[S_THETA]
    omega = state_f[S_OMEGA]
    x_prev = state_i[T_X_PREV]
    y_prev = state_i[T_Y_PREV]
    integrator = state_i[T_INTEGRATOR]
    applied = state_i[T_APPLIED]
    output = state_i[T_LAST]
    gm_left = state_i[T_GM_LEFT]

    drawn = 0
    n_samples = out_mean.shape[0]
    per_step = sensed.shape[0] == n_samples * decimation and decimation > 1
    per_sample = sensed.shape[0] > 1 and not per_step
    scale_per_sample = scale.shape[0] > 1
    offset_per_sample = offset.shape[0] > 1
    for j in range(n_samples):
        held = offset[j if offset_per_sample else 0]
        if n_components:
            if gm_left <= 0:
                for k in range(n_components):
                    gm_state[k] = gm_phi[k] * gm_state[k] + gm_drive[k] * normals[drawn]
                    drawn += 1
                gm_left = gm_block
            gm_left -= 1
            for k in range(n_components):
                held += gm_state[k]
        factor = scale[j if scale_per_sample else 0]
        if not per_step:
            held += sensed[j if per_sample else 0] * factor
        block_sum = 0.0
        block_flags = 0
        base = j * decimation
        for s in range(decimation):
            accel = held
            if per_step:
                accel += sensed[base + s] * factor
            if draw_white:
                accel += white_std * normals[drawn]
                drawn += 1
            # Pick-off, bridge, ADC: in open loop the latched bridge gives a fixed level
            # (eq. 16).
            volts = sense * theta + level
            if draw_adc:
                volts += adc_std * normals[drawn]
                drawn += 1
            code = np.int64(np.floor(volts + 0.5))
            if code > adc_fs:
                code = adc_fs
                block_flags |= 2
            elif code < -adc_fs:
                code = -adc_fs
                block_flags |= 2
            x = _round_shift(gain * code, _GAIN_SHIFT)
            if open_loop:
                # The open-loop readout keeps the 8 fraction bits of the FPGA word.
                output = _round_shift(x, _SIGNAL_SHIFT)
                reading = x / 256.0
                command = np.int64(0)
            else:
                y = _round_shift(a1 * y_prev + b0 * x + b1 * x_prev, _COEF_SHIFT)
                candidate = integrator + ki * y
                if candidate > integrator_limit:
                    candidate = integrator_limit
                elif candidate < -integrator_limit:
                    candidate = -integrator_limit
                command = _round_shift(y + _round_shift(candidate, _COEF_SHIFT), _SIGNAL_SHIFT)
                if command > da2_fs:
                    command = da2_fs
                    block_flags |= 1
                    if candidate < integrator:  # anti-windup: integrate only back into range
                        integrator = candidate
                elif command < -da2_fs:
                    command = -da2_fs
                    block_flags |= 1
                    if candidate > integrator:
                        integrator = candidate
                else:
                    integrator = candidate
                x_prev = x
                y_prev = y
                output = command
                reading = float(command)
            if output > range_counts or output < -range_counts:
                block_flags |= 4

            # Torquer acts with one step of computation delay; pendulum by exact ZOH.
            moment = k0 * accel - k_fb * applied + bias_moment
            theta_next = ad00 * theta + ad01 * omega + bd0 * moment
            omega = ad10 * theta + ad11 * omega + bd1 * moment
            theta = theta_next
            if theta > stop:
                theta = stop
                if omega > 0.0:
                    omega = 0.0
            elif theta < -stop:
                theta = -stop
                if omega < 0.0:
                    omega = 0.0
            applied = command
            block_sum += reading
        out_mean[j] = block_sum / decimation
        out_flags[j] = block_flags

    state_f[S_THETA] = theta
    state_f[S_OMEGA] = omega
    state_i[T_X_PREV] = x_prev
    state_i[T_Y_PREV] = y_prev
    state_i[T_INTEGRATOR] = integrator
    state_i[T_APPLIED] = applied
    state_i[T_LAST] = output
    state_i[T_GM_LEFT] = gm_left
    return drawn
