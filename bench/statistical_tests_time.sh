#!/bin/bash
# Time the seeded statistical tests that issue 31 rewrote (several seeds, bounds from
# the sampling distributions), in the source tree DIR (default: this work tree), with
# the python environment VENV (default .venv): the sum of their pytest call durations.
# Run it on two trees (e.g. `git archive` of the commit before) to compare.
set -e
VENV=${VENV:-.venv}
PY=$(cd "$VENV/bin" && pwd)/python
cd "${1:-.}"
PYTHONPATH=$PWD "$PY" -m pytest -q -p no:cacheprovider --durations=0 -vv \
  test/test_loop_model.py test/test_noise_covariance.py test/test_thermal.py \
  test/test_fleet.py test/test_estimation.py test/test_tempfit.py test/test_imu_navigation.py \
  -k "$(echo allan_deviation_at_one_second_matches_white_noise allan_floor_matches_bias_instability \
        published_covariance sensor_noise_and_quantization own_component_coefficients \
        uniform_aging standard_error_matches_the_scatter noisy_data_recovers \
        gyro_allan_deviation | sed 's/ / or /g')" \
  | awk '/ call /{n++; s+=$1} /passed|failed/{print} END{printf "%d calls, %.2f s in all\n", n, s}'
