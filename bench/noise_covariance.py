"""Check the published acceleration covariance and the noise defaults against the stream.

Run: ``.venv/bin/python bench/noise_covariance.py [--seconds 600] [--seed 5]``.

A static default sensor (``TriadConfig()``) for ``--seconds`` per axis: the per-sample
variance (each second's mean removed) over the published covariance, the overlapping Allan
deviation (allantools) at octave taus beside the noise model's, the ratio of ADEV(1 s) to
the white noise the covariance implies at the output's noise-equivalent bandwidth (with
Greenhall's equivalent degrees of freedom), and the rms in 0.1-10 Hz (Welch, 10 s
segments). Prints Markdown.
"""

import argparse
import math

import allantools
import numpy as np
from scipy import signal
from tqdm import tqdm

from qfa_ros.model.constants import MICRO_G
from qfa_ros.model.design import design_controller, LinearLoop, published_acceleration_variance
from qfa_ros.model.noise import allan_deviation_model
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig


def main():
    """Run the sensor, print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=600.0)
    parser.add_argument('--seed', type=int, default=5)
    args = parser.parse_args()
    config = TriadConfig()
    rate = config.sample_rate_hz
    controller = design_controller(config.hardware, config.loop_rate_hz, config.crossover_hz,
                                   config.integrator_ratio, config.lead_pole_ratio)
    white_share, adc_gain = LinearLoop(config.hardware, controller,
                                       config.loop_rate_hz).noise_shares(config.decimation)
    variance = published_acceleration_variance(config)
    triad = QfaTriad(config, rng=args.seed)
    chunks = int(math.ceil(args.seconds / 10.0))
    accel = np.concatenate([triad.run_for(10.0).accel for _ in tqdm(range(chunks),
                                                                  desc='stream, 10 s')])
    blocks = accel.reshape(-1, int(rate), 3)
    per_block = blocks.var(axis=1, ddof=1)
    n = config.noise.noise_density
    print('| quantity | value |\n|---|---|')
    print(f'| noise density N (IEEE 1293: ADEV(1 s) of the white part) '
          f'| {n / MICRO_G:g} µg/√Hz |')
    print(f'| white rms in 0–10 Hz, N √(2 · 10 Hz) | {n * math.sqrt(20) / MICRO_G:.2f} µg |')
    print(f'| white share (per-sample variance / N² f_s) | {white_share:.4f} |')
    print(f'| noise-equivalent bandwidth of the output | {white_share * rate / 2:.1f} Hz |')
    print(f'| ADC share of the covariance | '
          f'{1 - white_share * n ** 2 * rate / variance:.4f} |')
    print(f'| published σ = √covariance | {math.sqrt(variance) / MICRO_G:.2f} µg |')
    print(f'| stream per-sample variance / covariance | {per_block.mean() / variance:.4f} ± '
          f'{per_block.std(ddof=1) / math.sqrt(per_block.size) / variance:.4f} |')
    taus = [0.01, 0.1, 1.0, 10.0, 100.0]
    taus = [t for t in taus if t <= args.seconds / 8]
    adev = np.array([allantools.oadev(accel[:, axis], rate=rate, data_type='freq',
                                      taus=taus)[1] for axis in range(3)])
    pooled = np.sqrt(np.mean(adev ** 2, axis=0))
    print('\n| τ [s] | stream ADEV [µg] (3 axes pooled) | noise model [µg] |\n|---|---|---|')
    for tau, value in zip(taus, pooled):
        print(f'| {tau:g} | {value / MICRO_G:.3f} | '
              f'{allan_deviation_model(config.noise, tau) / MICRO_G:.3f} |')
    one = taus.index(1.0)
    edf = 3 * allantools.edf_greenhall(alpha=0, d=2, m=int(rate), N=len(accel),
                                       overlapping=True)
    implied = math.sqrt(variance / (white_share * rate))
    naive = math.sqrt(variance / rate)
    ratio = pooled[one] / implied
    print(f'\nADEV(1 s) {pooled[one] / MICRO_G:.3f} µg; implied by the covariance at the '
          f'noise-equivalent bandwidth {implied / MICRO_G:.3f} µg: ratio {ratio:.3f} ± '
          f'{ratio / math.sqrt(2 * edf):.3f} (1σ, edf {edf:.0f}); '
          f'naive √(cov / f_s) {naive / MICRO_G:.3f} µg: ratio {pooled[one] / naive:.3f}')
    freq, psd = signal.welch(accel - accel.mean(axis=0), fs=rate, nperseg=int(10 * rate),
                             axis=0)
    band = (freq > 0) & (freq <= 10.0)
    rms = math.sqrt(psd[band].mean(axis=1).sum() * (freq[1] - freq[0]))
    print(f'stream rms in 0.1–10 Hz: {rms / MICRO_G:.2f} µg (seed {args.seed}, '
          f'{args.seconds:g} s × 3 axes)')


if __name__ == '__main__':
    main()
