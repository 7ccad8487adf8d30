"""
Compile the kernels ``make run`` and ``make sim`` call into numba's cache (``make setup``).

Every compiled function has ``cache=True``, but a fresh clone has no cache: the first
start of the node or the simulator would compile its kernels, several seconds before the
first sample. ``python -m qfa_ros.cli.warm_cache`` runs, without DDS and without writing
anything but the cache, the node's model on its parameter defaults (those of
``config/qfa.yaml``) for as many samples as the node's warm-up, and ``qfa-sim static
--duration 1`` with its summary discarded, so that both find every kernel signature they
need in the cache.
"""

import contextlib
import io
import sys

from qfa_ros.cli import sim
from qfa_ros.ros.model_settings import input_profile, make_triad
from qfa_ros.ros.parameter_table import PARAMETERS
from qfa_ros.ros.stream import WARM_UP_SAMPLES


def main():
    """Run the node's model and the simulator once; return the simulator's status."""
    values = {spec.name: spec.default for spec in PARAMETERS}
    triad = make_triad(values, input_profile(values))
    output = triad.run(WARM_UP_SAMPLES)
    if triad.thermal is not None:
        triad.thermal.reading_c(output.v_temp)
    with contextlib.redirect_stdout(io.StringIO()):
        return sim.main(['static', '--duration', '1'])


if __name__ == '__main__':
    sys.exit(main())
