"""
Fleet studies: Monte Carlo over units, schedules and years, run on Dask.

A study file names how many units to draw, the schedule and its settings, the aging
horizon and calibration interval, and the environment; each unit is simulated from its
own seed (so results do not depend on how the work is split), batches of units run as
Dask tasks on a local cluster or an existing scheduler, and results land in Parquet.
It may import ``qfa_ros.calibration`` and ``qfa_ros.model``, dask, pyarrow, tqdm and
matplotlib; never ROS, never ``qfa_ros.bag``.
"""
