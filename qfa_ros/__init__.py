"""
Emulated self-calibrating IMU of digital closed-loop quartz flexible accelerometers.

The package is layered; each layer may import only the layers below it (checked by
import-linter in the test suite, see ``.importlinter``):

=================  =========================================================  ===========
layer              what                                                       may import
=================  =========================================================  ===========
``cli``            thin command-line entry points (qfa_node, qfa-sim, ...)    everything
``ros``            the node and its parts, replay publisher; the only rclpy   bag and below
``report``         figures drawn from bags (matplotlib)                       bag and below
``fleet``          Monte Carlo fleet studies on Dask, Parquet results         calibration, model
``bag``            MCAP / rosbag2 writing and reading, CDR, traces            calibration, model
``calibration``    self-estimation schedules, calibration state, temperature fits  model
``model``          the sensor physics: loops, noise, drift, thermal, triad    numpy/scipy/numba
=================  =========================================================  ===========
"""

VERSION = '1.0.0'
"""The release: package.xml's ``<version>`` (setup.py reads it there; test_package checks this)."""

__version__ = VERSION
