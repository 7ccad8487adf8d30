"""The README's service session, run against the node on its default parameters.

Run: ``.venv/bin/python bench/session.py``. Starts ``qfa_node`` in its own process (every
parameter at its default but ``output_dir`` and ``state_file``, which go to a scratch
directory), then through rclpy clients, as the README's ``ros2`` commands do: the static
output, ``capture_reference``, a drift, ``self_calibrate``, ``calibrate_temperature``,
each followed by the static output. Prints what docs/getting_started.md quotes. Static outputs are
2 s means minus the default unit's expected level output in gravity at latitude 45 deg.
"""

from pathlib import Path
import sys
import tempfile
import time

import numpy as np
from std_srvs.srv import Trigger

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from node_helpers import (  # noqa: E402
    Client,
    domain_id,
    ImuCollector,
    mean_accel,
    NODE,
    NodeProcess,
)

from qfa_ros.model.constants import MICRO_G
from qfa_ros.model.earth import normal_gravity  # noqa: E402

G = float(normal_gravity(np.radians(45.0)))


def static(client, imu, label):
    """Print the 2 s static mean minus (0, 0, gamma) [ug]."""
    mean = np.array(mean_accel(client, imu, 2000, timeout=120, settle_s=0.3))
    error = (mean - [0.0, 0.0, G]) / MICRO_G
    print(f'{label} [ug]: [{error[0]:.1f}, {error[1]:.1f}, {error[2]:.1f}]', flush=True)
    return error


def call(client, name, timeout):
    """Call a Trigger service of the node and print its answer with the wall time."""
    start = time.monotonic()
    response = client.call(Trigger, f'/{NODE}/{name}', Trigger.Request(), timeout=timeout)
    print(f'{name} ({time.monotonic() - start:.1f} s wall, success {response.success}): '
          f'{response.message}', flush=True)
    return response


def main():
    """Run the session and print it."""
    with tempfile.TemporaryDirectory() as scratch:
        domain = domain_id('session')
        node = NodeProcess(domain, scratch, {'output_dir': scratch,
                                             'state_file': str(Path(scratch) / 'state.json')})
        client = Client(domain)
        try:
            imu = ImuCollector(client, depth=5000)
            client.spin_until(lambda: len(imu.samples) > 100, 120, 'the first samples')
            static(client, imu, 'static output - (0, 0, gamma)')
            call(client, 'capture_reference', 300)
            client.set_parameters({'drift.feedback_ppm': [200.0, -150.0, 300.0],
                                   'drift.forward_ppm': [-200.0, 0.0, 0.0]})
            static(client, imu, 'drifted')
            call(client, 'self_calibrate', 300)
            static(client, imu, 'compensated')
            call(client, 'calibrate_temperature', 1800)
            static(client, imu, 'temperature compensated')
        finally:
            client.close()
            node.stop()


if __name__ == '__main__':
    main()
