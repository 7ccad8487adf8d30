"""
Which schedule settings change what a self-estimate expects (issue 28, settings-mismatch audit).

Captures the references with the node's default forward settings
(``estimation.forward.*``) and the issue's feedback settings (4 chopped cycles, 0.02 s
settle, 0.28 s average: the improved schedule's segments), then runs the estimate with
one setting changed on the same quiet, drift-free triad (no thermal model, noise off
but the converter's own): every ppm it reads is the setting's, not a drift. A setting
whose change moves the estimate beyond 1 ppm must match between reference and estimate
(the schedules refuse a mismatch); the others may differ. Also the loop and sample
rates (the node's ``loop_rate_hz`` / ``sample_rate_hz``, a state file carried to a node
restarted at another rate)::

    python bench/schedule_settings.py            # about 2 s of CPU
"""

import argparse
from dataclasses import replace
import time

import numpy as np

from qfa_ros.calibration.estimation import (
    capture_reference,
    feedback_schedule,
    forward_schedule,
    REFERENCE_SETTING_TOLERANCE_PPM,
)
from qfa_ros.calibration.schedule import run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.model.noise import NoiseConfig
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig
from qfa_ros.ros.model_settings import feedback_settings, forward_settings
from qfa_ros.ros.parameter_table import PARAMETERS

QUIET = NoiseConfig(noise_density=0.0, bias_instability=0.0)

FORWARD_CASES = [('points', 4), ('points', 6), ('step', 256), ('step', 512),
                 ('settle_s', 0.0), ('settle_s', 0.1), ('average_s', 0.1), ('average_s', 2.0),
                 ('order', 'bidirectional'), ('order', 'interleaved')]
FEEDBACK_CASES = [('cycles', 1), ('cycles', 16), ('settle_s', 0.0), ('settle_s', 0.2),
                  ('average_s', 1.12), ('average_s', 2.0), ('order', 'single'),
                  ('motion_limit', 1e-2), ('bias_instability', 0.0)]
RATE_CASES = [('sample_rate_hz', 500.0), ('loop_rate_hz', 20000.0)]


def estimate(forward, feedback, changed_forward, changed_feedback, config=None, seed=0,
             capture_feedback=None):
    """Capture with ``forward``/``feedback``; return the two estimates [ppm] with the changes."""
    triad = QfaTriad(TriadConfig(noise=QUIET), rng=seed)
    triad.run_for(0.2)
    state = CalibrationState()
    run_schedule(triad, capture_reference(triad, state, forward,
                                          capture_feedback or feedback))
    if config is not None:
        triad = QfaTriad(config, rng=seed)
        triad.run_for(0.2)
    ahead = run_schedule(triad, forward_schedule(triad, state, changed_forward, apply=False,
                                                 check_settings=False))
    back = run_schedule(triad, feedback_schedule(triad, state, changed_feedback, apply=False,
                                                 check_settings=False))
    return ahead.estimate_ppm, back.estimate_ppm


def main():
    argparse.ArgumentParser(description=__doc__.split('\n\n')[0]).parse_args()
    values = {spec.name: spec.default for spec in PARAMETERS}
    forward = forward_settings(values)
    feedback = replace(feedback_settings(values), cycles=4, settle_s=0.02, average_s=0.28,
                       order='chopped')
    started = time.process_time()
    print(f'reference: {forward}\n           {feedback}\n')
    print('| setting | reference | estimate | forward [ppm] x, y, z | feedback [ppm] x, y, z '
          '| must match |')
    print('|---|---|---|---|---|---|')
    rows = [('none', '', '', forward, feedback, None, None)]
    rows += [(f'forward.{n}', getattr(forward, n), v, replace(forward, **{n: v}), feedback,
              None, None) for n, v in FORWARD_CASES]
    rows += [(f'feedback.{n}', getattr(feedback, n), v, forward,
              replace(feedback, **{n: v}), None, None) for n, v in FEEDBACK_CASES]
    # The single order: does the number of cycles matter there?
    single = replace(feedback, order='single')
    for cycles in (1, 16):
        rows.append(('feedback.cycles (single order)', single.cycles, cycles, forward,
                     replace(single, cycles=cycles), None, single))
    for name, value in RATE_CASES:
        config = TriadConfig(noise=QUIET, **{name: value})
        rows.append((name, getattr(TriadConfig(), name), value, forward, feedback, config,
                     None))
    for name, ref, new, fwd, fb, config, capture in rows:
        ahead, back = estimate(forward, feedback, fwd, fb, config, capture_feedback=capture)
        moved = max(np.max(np.abs(ahead)), np.max(np.abs(back)))
        cells = [', '.join(f'{v:+.2f}' for v in e) for e in (ahead, back)]
        match = 'yes' if moved > REFERENCE_SETTING_TOLERANCE_PPM else 'no'
        print(f'| {name} | {ref} | {new} | {cells[0]} | {cells[1]} | {match} |')
    print(f'\nCPU {time.process_time() - started:.1f} s')


if __name__ == '__main__':
    main()
