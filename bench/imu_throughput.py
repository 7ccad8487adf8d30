"""Benchmark the full IMU (QFA loops + gyros on a trajectory) against accelerometers alone.

Run: ``.venv/bin/python bench/imu_throughput.py [--seconds S] [--repeat N]``. Prints
Markdown. Every case is ``qfa-sim``'s model loop (``QfaTriad.run_chunks`` in chunks of
``qfa_ros.cli.sim.CHUNK_SECONDS``, 1 kHz output, 10 kHz loops), interleaved in one
process so that machine load hits all alike:

- *static, accelerometers only*: level, no gyros (``TriadConfig(gyro=None)``), the
  ``qfa-sim static`` figure;
- *drive, full IMU*: the gyro triad and the built-in vehicle drive on the WGS-84 Earth
  (specific force and rate from the trajectory, ``qfa-sim trajectory --motion drive``);
- *static on the Earth*, with and without the gyros: level at latitude 45 deg, the
  node's default pose (one value per chunk, as a level ``StaticProfile``).

The acceptance figure is the ratio of their real-time multiples (issue 15: >= 0.90).
Each is measured on the wall clock and on the process's CPU time (sensor seconds per
CPU second): on a busy machine the CPU figure still compares the work done.
"""

import argparse
import statistics
import time


def run(make, seconds, chunk_seconds):
    """Return the real-time multiples (wall, CPU) of ``seconds`` of sensor time."""
    triad = make()
    triad.run(10)  # JIT and first-call costs outside the timing
    rate = triad.config.sample_rate_hz
    start = time.perf_counter()
    cpu = time.process_time()
    for _ in triad.run_chunks(int(round(seconds * rate)), int(round(chunk_seconds * rate))):
        pass
    return seconds / (time.perf_counter() - start), seconds / (time.process_time() - cpu)


def main():
    """Run the benchmark and print a Markdown table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--seconds', type=float, default=600.0,
                        help='sensor seconds per repetition (default: the drive, 620 s)')
    parser.add_argument('--repeat', type=int, default=3)
    args = parser.parse_args()

    from qfa_ros.cli.sim import CHUNK_SECONDS
    from qfa_ros.model import motion_scripts
    from qfa_ros.model.triad import QfaTriad
    from qfa_ros.model.triad_config import TriadConfig

    drive = motion_scripts.vehicle_drive()
    cases = {
        'static, accelerometers only': lambda: QfaTriad(TriadConfig(gyro=None), rng=0),
        'drive, full IMU (gyros + trajectory)': lambda: QfaTriad(TriadConfig(), rng=0,
                                                                 profile=drive),
        'static on the Earth, full IMU': lambda: QfaTriad(
            TriadConfig(), rng=0, profile=motion_scripts.static(45.0)),
        # The same input without the gyros: what the gyros cost, apart from the input.
        'static on the Earth, accelerometers only': lambda: QfaTriad(
            TriadConfig(gyro=None), rng=0, profile=motion_scripts.static(45.0)),
    }
    results = {name: [] for name in cases}
    names = list(cases)
    for repetition in range(args.repeat):
        # The order rotates: no case always runs first (fresh memory) or after the same one.
        for name in names[repetition % len(names):] + names[:repetition % len(names)]:
            results[name].append(run(cases[name], args.seconds, CHUNK_SECONDS))
    wall = {name: [w for w, _ in values] for name, values in results.items()}
    cpu = {name: [c for _, c in values] for name, values in results.items()}
    base = statistics.median(wall['static, accelerometers only'])
    base_cpu = statistics.median(cpu['static, accelerometers only'])
    print(f'{args.seconds:g} s of sensor time per run in {CHUNK_SECONDS:g} s chunks, '
          f'{args.repeat} interleaved repetitions (median; 1 kHz output, 10 kHz loops)\n')
    print('| case | x real time (median) | min | max | ratio to static accel-only '
          '| x real time per CPU second | CPU ratio |')
    print('|---|---|---|---|---|---|---|')
    for name in results:
        median = statistics.median(wall[name])
        per_cpu = statistics.median(cpu[name])
        print(f'| {name} | {median:.1f} | {min(wall[name]):.1f} | {max(wall[name]):.1f} | '
              f'{median / base:.3f} | {per_cpu:.1f} | {per_cpu / base_cpu:.3f} |')


if __name__ == '__main__':
    main()
