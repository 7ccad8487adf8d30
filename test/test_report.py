"""Tests of ``qfa-report``: figures from real estimation traces and scenario bags."""

import os
from pathlib import Path
import re
import struct
import subprocess
import sys

import matplotlib.image
import matplotlib.pyplot as plt
import numpy as np
import pytest

from qfa_ros.bag.estimation_trace import trace_path, write_estimation_trace
from qfa_ros.bag.scenario_bag import ScenarioBag
from qfa_ros.calibration.estimation import (
    capture_reference,
    FeedbackSettings,
    ForwardSettings,
    self_calibrate,
)
from qfa_ros.calibration.schedule import run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.calibration.temperature import temperature_schedule, TemperatureSettings
from qfa_ros.cli.report import main
from qfa_ros.model.constants import MICRO_G
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import AXES, QfaTriad
from qfa_ros.model.triad_config import TriadConfig
from qfa_ros.report.figures import build_figures, DPI, load_bag

FORWARD = ForwardSettings(points=5, average_s=0.1)
FEEDBACK = FeedbackSettings(average_s=0.5)
DRIFT_PPM = 200.0
PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
REPO = Path(__file__).resolve().parents[1]


def _drift(triad):
    for axis in range(len(AXES)):
        triad.drift.set_step(axis, 'k_amp', -DRIFT_PPM * 1e-6)
        triad.drift.set_step(axis, 'k_vi', 1 / (1 + DRIFT_PPM * 1e-6) - 1)


@pytest.fixture(scope='module')
def traces(tmp_path_factory):
    """Write a reference and a self-calibration trace file; return paths and results."""
    directory = tmp_path_factory.mktemp('traces')
    triad = QfaTriad(TriadConfig(), rng=1)
    state = CalibrationState()
    reference = run_schedule(triad, capture_reference(triad, state, FORWARD, FEEDBACK))
    reference_path = write_estimation_trace(
        trace_path(directory, 'reference', reference[-1].end_ns), 'reference', reference)
    _drift(triad)
    calibration = run_schedule(triad, self_calibrate(triad, state, FORWARD, FEEDBACK))
    calibration_path = write_estimation_trace(
        trace_path(directory, 'self_calibrate', calibration[-1].end_ns), 'self_calibrate',
        calibration)
    return {'directory': directory, 'paths': [reference_path, calibration_path],
            'reference': reference, 'calibration': calibration}


@pytest.fixture(scope='module')
def scenario(tmp_path_factory):
    """Write a paper-2019-like scenario bag: static phases around a self-calibration."""
    path = tmp_path_factory.mktemp('scenario') / 'paper.mcap'
    config = TriadConfig()
    triad = QfaTriad(config, rng=2)
    state = CalibrationState()
    samples = int(config.sample_rate_hz)
    static = {}
    with ScenarioBag(path, config) as bag:
        reference = run_schedule(triad, capture_reference(triad, state, FORWARD, FEEDBACK))

        def static_phase(name):
            bag.write_phase(name, triad.stamp_ns(triad.sample_index))
            output = triad.run(samples)
            bag.write_imu(output)
            static[name] = output.accel[output.valid.all(axis=1)]

        static_phase('reference')
        _drift(triad)
        static_phase('drifted')
        bag.write_phase('estimation', triad.stamp_ns(triad.sample_index))
        calibration = run_schedule(triad, self_calibrate(triad, state, FORWARD, FEEDBACK))
        static_phase('compensated')
        bag.write_trace('reference', 'reference', reference)
        bag.write_trace('self_calibrate', 'self_calibrate', calibration)
        bag.finish()
    return {'path': path, 'static': static, 'reference': reference,
            'calibration': calibration}


@pytest.fixture(scope='module')
def temperature(tmp_path_factory):
    """Write a temperature-cycle scenario bag from a short real calibration."""
    path = tmp_path_factory.mktemp('temperature') / 'temperature.mcap'
    # The shortest program (60 s, its 0.6 s blocks) and a 15 s body time constant (short
    # soaks): 35 fit points, 1.1 CPU-s; the figures' claim is that they plot what it wrote.
    config = TriadConfig(thermal=ThermalConfig(ambient_profile='constant', sensor_tau_s=15.0))
    triad = QfaTriad(config, rng=3)
    settings = TemperatureSettings(period_s=60.0, block_s=0.6, bins=20)
    with ScenarioBag(path, config) as bag:
        result = run_schedule(triad, temperature_schedule(triad, CalibrationState(), settings))
        bag.write_phase('cycle', result.start_ns)
        bag.write_temperature(result.blocks['time_ns'], result.blocks['temperature'])
        bag.write_trace('temperature', 'temperature', [result])
        bag.finish()
    return {'path': path, 'result': result}


def _figures(paths):
    figures = {item.name: item for item in build_figures(paths)}
    for item in figures.values():
        plt.close(item.figure)
    return figures


def assert_valid_png(path, min_width=800, min_height=400):
    """Check the PNG signature, its IHDR size and that it is not blank."""
    data = Path(path).read_bytes()
    assert data[:8] == PNG_SIGNATURE, path
    width, height = struct.unpack('>II', data[16:24])
    assert width >= min_width and height >= min_height, (path, width, height)
    pixels = matplotlib.image.imread(path)
    assert pixels.shape[:2] == (height, width)
    assert pixels[..., :3].std() > 0.05, f'{path} looks blank'


# --- trace files ---------------------------------------------------------------------------

@pytest.fixture(scope='module')
def trace_figures(traces):
    """
    Return the figures of the directory of the two trace files, built once.

    ``{name: ReportFigure}``. A directory is read like its files: the tests of its figures
    compare them with the runs written into each file. Files given one by one: the
    single-reference test and the command-line test.
    """
    return _figures([traces['directory']])


def test_forward_figure_plots_the_written_sweep(traces, trace_figures):
    data = trace_figures['forward_gain'].data
    reference, calibration = traces['reference'][0], traces['calibration'][0]
    assert set(data) == {'reference', 'self_calibrate'}
    for axis_index, axis in enumerate(AXES):
        plotted = data['reference'][axis]
        np.testing.assert_array_equal(plotted['delta_n'], reference.points['delta_n'])
        np.testing.assert_array_equal(plotted['n_out'], reference.points[f'mean_{axis}'])
        assert plotted['slope'] == pytest.approx(reference.measured[axis_index], rel=1e-10)
        drifted = data['self_calibrate'][axis]
        assert drifted['slope'] == pytest.approx(calibration.measured[axis_index], rel=1e-10)
        assert drifted['estimate_ppm'] == pytest.approx(calibration.estimate_ppm[axis_index])
        # The slope change read off the figure is the estimate of the trace.
        assert drifted['slope_change_ppm'] == pytest.approx(
            calibration.estimate_ppm[axis_index], abs=1e-3)
        assert drifted['slope_change_ppm'] == pytest.approx(-DRIFT_PPM, abs=5.0)


def test_feedback_figure_plots_the_written_segments(traces, trace_figures):
    data = trace_figures['feedback_gain'].data
    reference, calibration = traces['reference'][1], traces['calibration'][1]
    for axis_index, axis in enumerate(AXES):
        plotted = data['reference'][axis]
        np.testing.assert_array_equal(plotted['means'], reference.points[f'mean_{axis}'])
        np.testing.assert_array_equal(plotted['reference_on'],
                                      reference.points['reference_on'] > 0.5)
        assert plotted['step'] == pytest.approx(reference.measured[axis_index], rel=1e-10)
        drifted = data['self_calibrate'][axis]
        assert drifted['step'] == pytest.approx(calibration.measured[axis_index], rel=1e-10)
        # The estimate is reference/step - 1, the bar step/reference - 1.
        estimate = calibration.estimate_ppm[axis_index] * 1e-6
        assert drifted['step_change_ppm'] == pytest.approx((1 / (1 + estimate) - 1) * 1e6,
                                                           abs=1e-3)
        assert drifted['estimate_ppm'] == pytest.approx(calibration.estimate_ppm[axis_index])


def test_single_reference_file_plots_without_a_comparison(traces):
    figures = _figures(traces['paths'][:1])
    assert set(figures['forward_gain'].data) == {'reference'}
    assert 'deviation' in figures['forward_gain'].data['reference']['z']


# --- scenario bags -------------------------------------------------------------------------

def test_scenario_bag_loads_runs_imu_and_phases(scenario):
    contents = load_bag(scenario['path'])
    assert [run.name for run in contents.runs] == ['reference', 'self_calibrate']
    assert contents.runs[0].captured and not contents.runs[1].captured
    assert set(contents.runs[1].tables) == {'forward/points', 'forward/residuals',
                                            'feedback/points', 'feedback/residuals'}
    assert [name for _, name in contents.phases] == ['reference', 'drifted', 'estimation',
                                                     'compensated']
    assert len(contents.imu_time_ns) == sum(len(a) for a in scenario['static'].values())


def test_scenario_bag_gives_static_output_figure(scenario, tmp_path):
    figures = build_figures([scenario['path']])
    try:
        assert [item.name for item in figures] == ['forward_gain', 'feedback_gain',
                                                   'static_output']
        static = figures[-1]
        # The PNG of the figure only this bag draws (the others: the command-line test).
        static.figure.savefig(tmp_path / 'static_output.png', dpi=DPI)
    finally:
        for item in figures:
            plt.close(item.figure)
    assert_valid_png(tmp_path / 'static_output.png')
    data = static.data
    phases = data['phases']
    assert set(phases) == {'reference', 'drifted', 'compensated'}
    baseline = scenario['static']['reference'][:, 2].mean()
    assert data['baseline_m_s2'] == pytest.approx(baseline, rel=1e-12)
    for name, accel in scenario['static'].items():
        assert phases[name]['samples'] == len(accel)
        assert phases[name]['mean_m_s2'] == pytest.approx(accel[:, 2].mean(), rel=1e-12)
        assert phases[name]['error_ug'] == pytest.approx(
            (accel[:, 2].mean() - baseline) / MICRO_G, abs=1e-6)
    # 200 ppm of 1 g is 200 ug; the compensation removes most of it.
    assert 150 < abs(phases['drifted']['error_ug']) < 250
    assert abs(phases['compensated']['error_ug']) < 0.25 * abs(phases['drifted']['error_ug'])


def test_temperature_bag_gives_fit_and_compensation_figures(temperature):
    figures = _figures([temperature['path']])
    assert list(figures) == ['temperature_fit', 'temperature_compensation']
    result = temperature['result']
    order = np.argsort(result.points['v_temp'])
    for axis_index, axis in enumerate(AXES):
        fitted = figures['temperature_fit'].data[axis]
        np.testing.assert_allclose(fitted['v_temp'], result.points['v_temp'][order])
        np.testing.assert_allclose(fitted['bias_ug'],
                                   result.points[f'bias_{axis}'][order] / MICRO_G)
        fit = result.calibrations[axis_index].fit
        np.testing.assert_allclose(fitted['fit_ug'], fit.evaluate(fitted['fit_v']) / MICRO_G,
                                   rtol=1e-9, atol=1e-9)
        compensated = figures['temperature_compensation'].data[axis]
        np.testing.assert_allclose(compensated['after_ug'],
                                   result.points[f'compensated_{axis}'][order] / MICRO_G)
        calibration = result.calibrations[axis_index]
        assert compensated['p2p_before_ug'] == pytest.approx(calibration.p2p_before / MICRO_G)
        assert compensated['p2p_after_ug'] == pytest.approx(calibration.p2p_after / MICRO_G)


# --- command line --------------------------------------------------------------------------

def test_command_line_reports_missing_and_empty_inputs(tmp_path, capsys):
    assert main([str(tmp_path / 'missing.mcap')]) == 1
    assert 'no such file' in capsys.readouterr().err
    empty = tmp_path / 'empty'
    empty.mkdir()
    assert main([str(empty), '--out', str(tmp_path / 'out')]) == 1
    assert 'nothing to plot' in capsys.readouterr().err
    assert not (tmp_path / 'out').exists(), 'before: an empty output directory was left'


SECRET = b'SECRET-hunter2'


@pytest.mark.parametrize('case, expected', [
    ('text', 'not an MCAP file'),
    ('empty', 'truncated'),
    ('cut', 'cannot read MCAP'),
    ('fifo', 'not a regular file'),
    ('device', 'not a regular file'),
    ('not imu', '/qfa/scenario/phase is not sensor_msgs/msg/Imu'),
])
def test_a_malformed_bag_is_one_line_naming_it_without_quoting_it(scenario, tmp_path, capsys,
                                                                   case, expected):
    """Before: a traceback (mcap, zstd, struct errors), a FIFO blocked, a String decoded."""
    from qfa_ros.bag.reader import BagError, BagSource
    bag = tmp_path / 'bag.mcap'
    data = Path(scenario['path']).read_bytes()
    if case == 'fifo':
        os.mkfifo(bag)
    elif case == 'device':
        bag.symlink_to('/dev/zero')
    else:
        bag.write_bytes({'text': SECRET * 10, 'empty': b'', 'cut': data[:100],
                         'not imu': data}[case])
    topic = ['--topic', '/qfa/scenario/phase'] if case == 'not imu' else []
    assert main(['imu-yaml', str(bag), *topic]) == 1
    err = capsys.readouterr().err
    assert expected in err and str(bag) in err and err.count('\n') == 1
    assert 'SECRET' not in err and '83, 69' not in err
    if case == 'not imu':
        return
    assert main([str(bag), '--out', str(tmp_path / 'out')]) == 1
    err = capsys.readouterr().err
    assert expected in err and err.count('\n') == 1 and 'SECRET' not in err
    assert not (tmp_path / 'out').exists()
    with pytest.raises(BagError, match='no bag' if case in ('fifo', 'device') else expected
                       ) as caught:
        BagSource(bag)
    assert 'SECRET' not in str(caught.value) and '83, 69' not in str(caught.value)


def test_command_line_writes_the_pngs_headless(traces, tmp_path):
    """
    ``qfa-report`` on trace files and the example temperature bag: every PNG, named in order.

    It draws without a display: no DISPLAY, no backend configured.
    """
    env = {key: value for key, value in os.environ.items()
           if key not in ('DISPLAY', 'WAYLAND_DISPLAY', 'MPLBACKEND')}
    out = tmp_path / 'figures'
    inputs = [*traces['paths'], REPO / 'bags' / 'temperature_cycle.mcap']
    result = subprocess.run(
        [sys.executable, '-m', 'qfa_ros.cli.report', *map(str, inputs), '--out', str(out)],
        env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    names = ['forward_gain.png', 'feedback_gain.png', 'temperature_fit.png',
             'temperature_compensation.png']
    assert result.stdout.split() == [str(out / name) for name in names]
    for name in names:
        assert_valid_png(out / name)


def test_documented_figures_exist_and_include_the_reports_figures():
    # The README shows one; the docs pages show the rest (docs/replay_report.md).
    texts = [(REPO / 'README.md').read_text()]
    texts += [path.read_text() for path in (REPO / 'docs').glob('*.md')]
    referenced = {name for text in texts
                  for name in re.findall(r'figures/([a-z0-9_]+\.png)', text)}
    reports = {'forward_gain.png', 'feedback_gain.png', 'static_output.png',
               'temperature_fit.png', 'temperature_compensation.png'}
    assert reports <= referenced
    assert 'static_output.png' in re.findall(r'docs/figures/([a-z_]+\.png)', texts[0])
    for name in reports:
        assert_valid_png(REPO / 'docs' / 'figures' / name)
    for name in referenced - reports:  # other tools' figures (qfa-fleet, bench/)
        assert (REPO / 'docs' / 'figures' / name).read_bytes()[:8] == PNG_SIGNATURE, name
