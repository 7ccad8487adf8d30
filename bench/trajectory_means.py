"""Benchmark ``Trajectory.sample_means``: the per-piece fits against the old two-point Gauss.

Run: ``.venv/bin/python bench/trajectory_means.py [--seconds S] [--repeats R] [--old REV]``.
Prints Markdown: CPU ms per sensor second at 1 kHz, 1 s calls as the triad makes them,
from t = 10 s on fresh trajectories (so the fits are built inside the timing), the median
of ``R`` runs. Three ways side by side, interleaved in one process: the old code
(``qfa_ros/model/trajectory.py`` at git revision ``REV``, before the fits, loaded from
git), the fits integrated sample by sample (``PiecewiseMeans(fast=False)``), and the
fits with each segment's mean polynomial for the samples inside it (the default).
"""

import argparse
import importlib.util
import pathlib
import statistics
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
    return (time.process_time() - start) / int(seconds) * 1e3


def main():
    """Run the benchmark and print a Markdown table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--seconds', type=float, default=30.0, help='sensor seconds a case')
    parser.add_argument('--repeats', type=int, default=5, help='runs a case (median)')
    parser.add_argument('--old', default='c4d7d2e', help='git revision of the old code')
    args = parser.parse_args()
    from qfa_ros.model import trajectories
    from qfa_ros.model.trajectory_means import PiecewiseMeans
    old = load_old(args.old)

    def integrated(name):
        motion = getattr(trajectories, name)()
        motion._means = PiecewiseMeans(motion._c, motion._x, fast=False)
        return motion

    ways = {'old': lambda name: getattr(old, name)(), 'integrated': integrated,
            'fast': lambda name: getattr(trajectories, name)()}
    names = ('vehicle_drive', 'coning', 'sculling', 'rate_table_turn', 'six_position_tumble')
    for make in ways.values():  # compile outside the timing
        for name in names:
            make(name).sample_means(0.0, 1e-3, 10)
    print(f'{args.seconds:g} sensor seconds at 1 kHz from t = 10 s, 1 s calls, CPU time, '
          f'median of {args.repeats}\n')
    print('| trajectory | pieces / s | old GL2 [ms / sensor s] | integrated [ms / sensor s] '
          '| fast [ms / sensor s] | old / fast | integrated / fast |')
    print('|---|---|---|---|---|---|---|')
    for name in names:
        runs = {way: [] for way in ways}
        for _ in range(args.repeats):
            for way, make in ways.items():
                runs[way].append(cost(make(name), args.seconds))
        ms = {way: statistics.median(values) for way, values in runs.items()}
        motion = getattr(trajectories, name)()
        pieces = (len(motion.poly.x) - 1) / motion.duration
        print(f'| {name}() | {pieces:.3g} | {ms["old"]:.3f} | {ms["integrated"]:.3f} '
              f'| {ms["fast"]:.3f} | {ms["old"] / ms["fast"]:.2f} '
              f'| {ms["integrated"] / ms["fast"]:.2f} |')


if __name__ == '__main__':
    main()
