"""Benchmark the loop kernel: axis-steps/s, real-time multiple, JIT compile time, RSS.

Run: ``.venv/bin/python bench/loop_throughput.py`` (``make bench``). Prints Markdown.
"""

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

COMPILE_SNIPPET = """
import time
t = time.perf_counter()
from qfa_ros.model.triad import QfaTriad, TriadConfig
QfaTriad(TriadConfig(), rng=0).run(1)
print(time.perf_counter() - t)
"""


def compile_time(cache_dir):
    """Return seconds to import and run one sample in a fresh process."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    out = subprocess.run([sys.executable, '-c', COMPILE_SNIPPET], env=env,
                         capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main():
    """Run the benchmark and print a Markdown table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--seconds', type=float, default=60.0,
                        help='sensor seconds per repetition')
    parser.add_argument('--repeat', type=int, default=5)
    args = parser.parse_args()

    from qfa_ros.model import kernel
    from qfa_ros.model.noise import NoiseConfig
    from qfa_ros.model.triad import QfaTriad, TriadConfig

    with tempfile.TemporaryDirectory() as cache:
        cold = compile_time(cache)
        cached = statistics.median(compile_time(cache) for _ in range(3))

    # Kernel alone: one axis, noise pre-generated, 10 kHz loop.
    triad = QfaTriad(TriadConfig(noise=NoiseConfig.off()), rng=0)
    loop = triad.axes[2]
    steps = 1_000_000
    accel = np.full(steps, 9.80665)
    adc = np.random.default_rng(0).standard_normal(steps) * 0.5
    mean = np.empty(steps // 10)
    flags = np.empty(steps // 10, dtype=np.int8)
    rates = []
    for _ in range(args.repeat):
        start = time.perf_counter()
        kernel.run_axis(accel, adc, 10, loop.params_f, loop.params_i, loop.state_f,
                        loop.state_i, mean, flags)
        rates.append(steps / (time.perf_counter() - start))
    kernel_rate = statistics.median(rates)

    # Whole triad with noise generation, as qfa-sim runs it (1 s chunks).
    multiples = []
    for seed in range(args.repeat):
        triad = QfaTriad(TriadConfig(), rng=seed)
        start = time.perf_counter()
        for _ in range(int(args.seconds)):
            triad.run(1000)
        multiples.append(args.seconds / (time.perf_counter() - start))
    realtime = statistics.median(multiples)
    triad_rate = realtime * 3 * 10000
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    print('| measure | median | target |')
    print('|---|---|---|')
    print(f'| kernel, one axis, noise pre-generated | {kernel_rate / 1e6:.1f} M axis-steps/s '
          '| >= 10 M |')
    print(f'| triad incl. noise generation (3 x 10 kHz) | {triad_rate / 1e6:.1f} M axis-steps/s '
          f'= {realtime:.0f}x real time | >= 300x |')
    print(f'| JIT compile + first sample, cold cache | {cold:.2f} s | |')
    print(f'| same, cached (`cache=True`) | {cached:.2f} s | |')
    print(f'| peak RSS of this benchmark | {rss_mb:.0f} MB | |')
    print(f'\n{args.repeat} repetitions of {args.seconds:g} s sensor time; '
          f'kernel spread {min(rates) / 1e6:.1f}-{max(rates) / 1e6:.1f} M/s; '
          f'triad spread {min(multiples):.0f}-{max(multiples):.0f}x.')


if __name__ == '__main__':
    main()
