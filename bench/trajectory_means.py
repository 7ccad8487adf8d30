"""Benchmark ``Trajectory.sample_means``: the per-piece fits against the old two-point Gauss.

Run: ``.venv/bin/python bench/trajectory_means.py [--seconds S] [--old REV]``. Prints
Markdown: CPU ms per sensor second at 1 kHz, 1 s calls as the triad makes them, from
t = 10 s on fresh trajectories (so the fits are built inside the timing). The old code
is ``qfa_ros/model/trajectory.py`` at git revision ``REV`` (before the fits), loaded
from git beside the new one and run interleaved in the same process.
"""

import argparse
import importlib.util
import pathlib
import subprocess
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent


def load_old(revision):
    """Return the trajectory module of ``revision`` as a module object."""
    source = subprocess.run(['git', 'show', f'{revision}:qfa_ros/model/trajectory.py'],
                            cwd=ROOT, check=True, capture_output=True, text=True).stdout
    path = pathlib.Path(tempfile.mkdtemp()) / 'old_trajectory.py'
    path.write_text(source)
    spec = importlib.util.spec_from_file_location('old_trajectory', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def cost(motion, seconds, rate_hz=1000.0):
    """Return the CPU ms per sensor second of ``sample_means`` over 1 s calls."""
    n = int(rate_hz)
    start = time.process_time()
    for k in range(int(seconds)):
        motion.sample_means(10.0 + k, 1.0 / rate_hz, n)
    return (time.process_time() - start) / seconds * 1e3


def main():
    """Run the benchmark and print a Markdown table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--seconds', type=float, default=30.0, help='sensor seconds a case')
    parser.add_argument('--old', default='c4d7d2e', help='git revision of the old code')
    args = parser.parse_args()
    from qfa_ros.model import trajectory
    old = load_old(args.old)
    names = ('vehicle_drive', 'coning', 'sculling', 'rate_table_turn', 'six_position_tumble')
    for module in (old, trajectory):  # compile outside the timing
        for name in names:
            getattr(module, name)().sample_means(0.0, 1e-3, 10)
    print(f'{args.seconds:g} sensor seconds at 1 kHz from t = 10 s, 1 s calls, CPU time\n')
    print('| trajectory | pieces / s | old GL2 [ms / sensor s] | new [ms / sensor s] '
          '| old / new |')
    print('|---|---|---|---|---|')
    for name in names:
        motion = getattr(trajectory, name)()
        old_ms = cost(getattr(old, name)(), args.seconds)
        new_ms = cost(motion, args.seconds)
        pieces = (len(motion.poly.x) - 1) / motion.duration
        print(f'| {name}() | {pieces:.3g} | {old_ms:.3f} | {new_ms:.3f} '
              f'| {old_ms / new_ms:.2f} |')


if __name__ == '__main__':
    main()
