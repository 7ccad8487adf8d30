"""Benchmark the loop kernel: axis-steps/s, real-time multiple, JIT compile time, RSS.

Run: ``.venv/bin/python bench/loop_throughput.py`` (``make bench``). Prints Markdown.
In-process windows without start-up or summary; the whole ``qfa-sim`` process against
the limit of the loop is ``bench/sim_limit.py``.
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

from qfa_ros.model.constants import STANDARD_GRAVITY

COMPILE_SNIPPET = """
import time
t = time.perf_counter()
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig
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

    from qfa_ros.cli.sim import static_sensor
    from qfa_ros.model.noise import NoiseConfig
    from qfa_ros.model.parallel import available_cores
    from qfa_ros.model.triad import QfaTriad
    from qfa_ros.model.triad_config import TriadConfig

    with tempfile.TemporaryDirectory() as cache:
        cold = compile_time(cache)
        cached = statistics.median(compile_time(cache) for _ in range(3))

    # Kernel alone: one axis, 10 kHz loop, level; its noise (normals drawn, then the loop) or none.
    kernel_rates = {}
    for label, noise in (('noise', NoiseConfig()), ('quiet', NoiseConfig.off())):
        loop = QfaTriad(TriadConfig(noise=noise), rng=0).axes[2]
        samples = 100_000
        mean = np.empty(samples)
        flags = np.empty(samples, dtype=np.int8)
        rates = []
        for _ in range(args.repeat):
            start, cpu = time.perf_counter(), time.thread_time()
            loop.run(np.array([STANDARD_GRAVITY]), np.ones(1), np.zeros(1), 10, mean, flags)
            rates.append((samples * 10 / (time.perf_counter() - start),
                          samples * 10 / (time.thread_time() - cpu)))
        kernel_rates[label] = rates

    # The triad as qfa-sim static runs it: the node's default sensor, 10 s chunks.
    config, profile = static_sensor()
    multiples = {}
    for workers in (available_cores(), 1):
        multiples[workers] = []
        for seed in range(args.repeat):
            triad = QfaTriad(config, rng=seed, profile=profile)
            triad.workers = workers
            start = time.perf_counter()
            for _ in range(int(args.seconds // 10)):
                triad.run(10_000)
            multiples[workers].append(args.seconds / (time.perf_counter() - start))
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    def median(values, column=None):
        return statistics.median(v if column is None else v[column] for v in values)

    print('| measure | median | target |')
    print('|---|---|---|')
    for label, text, target in (('noise', 'with its noise', '>= 20 M'),
                                ('quiet', 'noise off', '')):
        rates = kernel_rates[label]
        print(f'| kernel, one axis, {text} | {median(rates, 0) / 1e6:.1f} M axis-steps/s '
              f'(CPU time: {median(rates, 1) / 1e6:.1f} M) | {target} |')
    cores = available_cores()
    for workers in multiples:
        realtime = median(multiples[workers])
        print(f'| triad, default sensor (thermal on), {workers} thread(s) | '
              f'{realtime * 3 * 10000 / 1e6:.1f} M axis-steps/s = {realtime:.0f}x real time '
              f'| {">= 720x" if workers == cores else ""} |')
    print(f'| JIT compile + first sample, cold cache | {cold:.2f} s | |')
    print(f'| same, cached (`cache=True`) | {cached:.2f} s | |')
    print(f'| peak RSS of this benchmark | {rss_mb:.0f} MB | |')
    spreads = ', '.join(f'{workers} thread(s) {min(m):.0f}-{max(m):.0f}x'
                        for workers, m in multiples.items())
    print(f'\n{args.repeat} repetitions of {args.seconds:g} s sensor time, {cores} cores; '
          f'spreads: {spreads}.')


if __name__ == '__main__':
    main()
