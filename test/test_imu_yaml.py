"""
imu.yaml for Kalibr, OpenVINS and allan_variance_ros (issue 38): what it says, and back.

A configuration's figures are Kalibr's definitions of its noise model, exactly; a bag's
are allan_variance_ros's fit, with the white-noise density beside it. Both are checked
against an Allan deviation computed by allantools (not the project's
``qfa_ros.model.allan``) on the recorded stream: the variance the figures predict at each
tau, ``N^2 / tau + K^2 tau / 3``, against the measured one, within the chi-square bounds
of its equivalent degrees of freedom (``statistics_helpers``).
"""

import math
from pathlib import Path

import allantools
import numpy as np
import pytest
from statistics_helpers import assert_variance_ratios
import yaml

from qfa_ros.bag import imu_series
from qfa_ros.bag.imu_series import read_imu
from qfa_ros.calibration.kalibr_yaml import load_imu_yaml, parse_imu_yaml
from qfa_ros.cli import report, sim
from qfa_ros.model.noise_figures import (
    config_figures,
    emulated_config,
    ImuNoiseFigures,
    KEYS,
    model_fit_figures,
)
from qfa_ros.ros.model_settings import load_imu_noise, triad_config
from qfa_ros.ros.parameter_table import PARAMETERS

ROOT = Path(__file__).resolve().parents[1]
RATE_HZ = 1000.0
SECRET = 'SECRET_TOKEN=hunter2-do-not-echo'
KALIBR_YAML = """\
#Accelerometer
accelerometer_noise_density: 2.0e-05 #Noise density (continuous-time)
accelerometer_random_walk: 1.0e-04   #Bias random walk
#Gyroscope
gyroscope_noise_density: 1.0e-06
gyroscope_random_walk: 1e-06         # what Python's repr writes: a string to PyYAML
rostopic: '/imu0'
update_rate: 200.0
"""
"""An imu.yaml as Kalibr's users write them (the random walks as large against the white
noise as EuRoC's ADIS16448: they rule the Allan deviation from 0.35 s (accelerometers)
and 1.7 s (gyros) on, where a five-minute bag has hundreds of degrees of freedom)."""


def defaults(**changes):
    values = {spec.name: spec.default for spec in PARAMETERS}
    values.update(changes)
    return values


BAG_S = 120.0
"""Length of the tests' static bags [s]: the fits reach 12 s, a tenth of it (one-hour bags:
bench/imu_yaml.py, bench/results/imu_yaml.md)."""


def static_bag(tmp_path, monkeypatch, *args):
    """
    Return (bag path, accel, rate) of a two-minute ``qfa-sim static`` bag.

    ``qfa-report imu-yaml`` reads the bag with the same :func:`read_imu` call: it gets
    copies of what this one decoded (the call checked to be for this bag and topic), not a
    second decoding of the same file (1.4 CPU-s a bag).
    """
    bag = tmp_path / 'static.mcap'
    assert sim.main(['static', '--duration', str(BAG_S), '--out', str(bag), *args]) == 0
    stamps, accel, rate = read_imu(bag)
    assert len(stamps) == BAG_S * RATE_HZ and np.all(np.diff(stamps) == 1_000_000)

    def read_again(path, topic='/imu/data_raw'):
        if Path(path) != bag or topic != '/imu/data_raw':
            return read_imu(path, topic)
        return stamps.copy(), accel.copy(), rate.copy()

    monkeypatch.setattr(imu_series, 'read_imu', read_again)
    return bag, accel, rate


def report_yaml(source, path, *args):
    """Return (figures, {key: line}) of ``qfa-report imu-yaml SOURCE``."""
    assert report.main(['imu-yaml', str(source), '--out', str(path), *args]) == 0
    text = path.read_text()
    lines = {line.split(':')[0]: line for line in text.splitlines() if not line.startswith('#')}
    return yaml.safe_load(text), lines


def edf_bound(samples, tau, white, walk):
    """Return the smaller of white FM's and random-walk FM's overlapping-AVAR edf at tau."""
    m = int(round(tau * RATE_HZ))
    return min(allantools.edf_greenhall(alpha=alpha, d=2, m=m, N=samples, overlapping=True)
               for alpha in ((0, -2) if walk else (0,)))


def assert_figures_predict_the_stream(accel, rate, figures, taus):
    """
    Check the Allan variance of each axis (allantools) against the figures' prediction.

    Returns the ratios measured / predicted, (6, len(taus)): accelerometers then gyros.
    """
    ratios, edf = [], None
    for data, name in ((accel, 'accelerometer'), (rate, 'gyroscope')):
        white = figures[f'{name}_noise_density']
        walk = figures[f'{name}_random_walk']
        for axis in range(3):
            used, adev, _, _ = allantools.oadev(data[:, axis], rate=RATE_HZ, data_type='freq',
                                                taus=np.asarray(taus))
            assert np.allclose(used, taus)
            ratios.append(adev ** 2 / (white ** 2 / used + walk ** 2 * used / 3.0))
        edf_name = [edf_bound(len(data), t, white, walk) for t in taus]
        edf = edf_name if edf is None else np.minimum(edf, edf_name)
    ratios = np.array(ratios)
    assert_variance_ratios(ratios, edf, checks=ratios.size + len(taus))
    return ratios


def test_the_configuration_imu_yaml_is_what_an_independent_allan_deviation_gives(tmp_path,
                                                                                 monkeypatch):
    # Issue 38: qfa-report imu-yaml config/qfa.yaml wrote 2.50e-5 for a white density of
    # 1.47e-5 (allan_variance_ros's line absorbed the bias instability), and random walks
    # that moved 2x and 7x with --max-tau. Now Kalibr's definitions: the white noise the
    # stream has at short tau, the random walk the bias processes drive it with. The
    # Allan variance they predict is the stream's, tau by tau, from 0.1 s (white) to 3 s
    # (the accelerometers' bias walk 46 % of it).
    figures, lines = report_yaml(ROOT / 'config' / 'qfa.yaml', tmp_path / 'config.yaml')
    expected = config_figures(triad_config(defaults()))
    assert [figures[key] for key in KEYS] == [getattr(expected, key) for key in KEYS]
    assert figures['accelerometer_noise_density'] == pytest.approx(1.471e-5, rel=1e-3)
    assert figures['accelerometer_random_walk'] == pytest.approx(7.587e-6, rel=1e-3)
    assert figures['gyroscope_noise_density'] == pytest.approx(5.818e-7, rel=1e-3)
    assert figures['gyroscope_random_walk'] == pytest.approx(2.878e-8, rel=1e-3)
    assert 'white noise of the published stream' in lines['accelerometer_noise_density']
    assert 'driving density' in lines['accelerometer_random_walk']
    assert all('#' in lines[key] for key in KEYS + ('update_rate', 'rostopic'))
    # No fit range enters them.
    assert report.main(['imu-yaml', str(ROOT / 'config' / 'qfa.yaml'), '--max-tau', '60']) \
        == 1
    bag, accel, rate = static_bag(tmp_path, monkeypatch, '--seed', '6')
    assert_figures_predict_the_stream(accel, rate, figures, [0.1, 0.3, 1.0, 3.0])
    # The bag's imu.yaml: allan_variance_ros's fit, said so, as the configuration's model
    # curve gives it over the same range (each within 4 of its bounds, plus the worst
    # of three axes), and the white density beside the accelerometers' (where the two
    # differ) within 4 of its bound of the configuration's.
    measured, lines = report_yaml(bag, tmp_path / 'bag.yaml')
    assert measured['update_rate'] == figures['update_rate'] == 1000.0
    assert measured['rostopic'] == figures['rostopic'] == '/imu/data_raw'
    fit = model_fit_figures(triad_config(defaults()), BAG_S / 10)
    for key in KEYS:
        assert 'allan_variance_ros fit' in lines[key], lines[key]
        bound = float(lines[key].split('relative uncertainty <= ')[1].split()[0])
        assert 0 < bound < 0.3 and abs(math.log(measured[key] / fit[key])) < 4 * bound, \
            (key, measured[key] / fit[key], bound)
    beside = lines['accelerometer_noise_density'].split('white noise at short tau')[1]
    white = float(beside.split('): ')[1].split(',')[0])
    bound = float(beside.split('relative uncertainty <= ')[1].split()[0])
    assert abs(math.log(white / figures['accelerometer_noise_density'])) < 4 * bound
    assert 'white noise at short tau' not in lines['gyroscope_noise_density']


def test_an_imu_yaml_goes_round_a_static_bag_and_comes_back(tmp_path, monkeypatch):
    # Your own IMU's noise: qfa-sim (and the node: noise.imu_yaml, test_node_ins) takes a
    # Kalibr imu.yaml and emulates it under the QFA loop; the bag's Allan variance is what
    # the file's figures predict, and qfa-report imu-yaml gives them back: the white
    # densities directly, the fits as allan_variance_ros reads the file's model curve.
    source = tmp_path / 'imu.yaml'
    source.write_text(KALIBR_YAML)
    figures = load_imu_yaml(source).as_dict()
    assert figures == {'accelerometer_noise_density': 2.0e-5, 'accelerometer_random_walk': 1.0e-4,
                       'gyroscope_noise_density': 1.0e-6, 'gyroscope_random_walk': 1.0e-6}
    bag, accel, rate = static_bag(tmp_path, monkeypatch, '--seed', '3', '--imu-yaml', str(source))
    taus = np.array([0.1, 0.3, 1.0, 3.0, 10.0])
    ratios = assert_figures_predict_the_stream(accel, rate, figures, taus)
    # The random walks are there: at 10 s the Allan variance is 830 (accelerometers) and
    # 34 (gyros) times the white noise's (without them, once).
    for rows, name, least in ((ratios[:3], 'accelerometer', 100.0),
                              (ratios[3:], 'gyroscope', 5.0)):
        white = figures[f'{name}_noise_density'] ** 2 / taus[-1]
        walk = figures[f'{name}_random_walk'] ** 2 * taus[-1] / 3
        assert np.mean(rows[:, -1]) * (white + walk) / white > least, name
    measured, lines = report_yaml(bag, tmp_path / 'bag.yaml')
    emulated = emulated_config(sim.static_sensor()[0], ImuNoiseFigures(**figures))
    fit = model_fit_figures(emulated, BAG_S / 10)
    for key in KEYS:
        bound = float(lines[key].split('relative uncertainty <= ')[1].split()[0])
        assert abs(math.log(measured[key] / fit[key])) < 4 * bound, \
            (key, measured[key] / fit[key], bound)
    beside = lines['accelerometer_noise_density'].split('white noise at short tau')[1]
    white = float(beside.split('): ')[1].split(',')[0])
    bound = float(beside.split('relative uncertainty <= ')[1].split()[0])
    assert abs(math.log(white / figures['accelerometer_noise_density'])) < 4 * bound
    # A node parameter file naming the imu.yaml gives it back exactly: the emulation adds
    # to the injected white noise what the loop's ADC leaves (2e-9), nothing else.
    params = tmp_path / 'params.yaml'
    params.write_text(f"/**:\n  ros__parameters:\n    noise.imu_yaml: '{source}'\n")
    back, lines = report_yaml(params, tmp_path / 'back.yaml')
    assert [back[key] for key in KEYS] == pytest.approx([figures[key] for key in KEYS],
                                                       rel=1e-12)
    assert all(f'emulated: noise.imu_yaml {source}' in lines[key] for key in KEYS)


def test_imu_yaml_of_an_ideal_sensor_is_zero_and_bad_input_is_refused(tmp_path, capsys):
    config = tmp_path / 'ideal.yaml'
    config.write_text("qfa_node:\n  ros__parameters:\n    sensor.error_profile: 'ideal'\n"
                      '    sample_rate_hz: 200.0\n')
    assert report.main(['imu-yaml', str(config)]) == 0
    text = capsys.readouterr().out
    figures = yaml.safe_load(text)
    assert figures['update_rate'] == 200.0
    assert [figures[key] for key in KEYS] == [0.0] * 4
    assert 'no white noise' in text and 'no bias process' in text
    assert report.main(['imu-yaml', str(tmp_path / 'missing.mcap')]) == 1
    # qfa-sim takes an imu.yaml where it runs the sensor as configured, not elsewhere.
    source = tmp_path / 'imu.yaml'
    source.write_text(KALIBR_YAML)
    assert sim.main(['paper-2019', '--imu-yaml', str(source)]) == 2
    assert 'static and trajectory' in capsys.readouterr().err
    assert sim.main(['static', '--duration', '1', '--imu-yaml', str(tmp_path / 'no')]) == 2
    assert 'cannot open' in capsys.readouterr().err


def refusal(content):
    """Return why the bytes ``content`` are no imu.yaml, checked to quote none of them."""
    with pytest.raises(ValueError) as caught:
        parse_imu_yaml(content.encode() if isinstance(content, str) else content, 'imu.yaml')
    message = str(caught.value)
    assert SECRET not in message and 'hunter2' not in message and '\n' not in message
    return message


@pytest.mark.parametrize('content, expected', [
    (f'{SECRET}: [1, 2\n', 'not a YAML document'),
    (f'- {SECRET}\n', 'not a mapping of Kalibr keys'),
    (KALIBR_YAML.replace('accelerometer_random_walk', SECRET), 'no accelerometer_random_walk'),
    (KALIBR_YAML.replace('1.0e-06', f"'{SECRET}'"), 'gyroscope_noise_density must be a number'),
    (KALIBR_YAML.replace('2.0e-05 #Noise', '.nan #Noise'), 'must be a number in [0,'),
    (KALIBR_YAML.replace('2.0e-05 #Noise', '-1.0e-05 #Noise'), 'must be a number in [0,'),
    (KALIBR_YAML.replace('1e-06 ', '1.0e+03 '), 'gyroscope_random_walk must be a number in [0,'),
    (KALIBR_YAML.replace('1.0e-06', 'true'), 'gyroscope_noise_density must be a number'),
    # An integer beyond the float range (OverflowError before).
    (KALIBR_YAML.replace('2.0e-05 #Noise', '1' + '0' * 400 + ' #Noise'),
     'must be a number in [0,'),
    # Deeper than PyYAML's recursive composer goes (RecursionError from about 500 levels;
    # its scanner's cost grows with the square of the depth: 1.3 CPU-s at 100 000).
    ('[' * 1000, 'not a YAML document'),
    (b'\xff\xfe' + SECRET.encode(), 'not UTF-8'),
])
def test_a_bad_imu_yaml_is_refused_without_quoting_it(content, expected):
    assert expected in refusal(content)


@pytest.mark.parametrize('content, expected', [
    # Before: a RecursionError traceback, a YAML error quoting the file, a dict.update
    # message naming nothing.
    ('[' * 1000, 'not a YAML document'),
    (f'{SECRET}: [1, 2\n', 'not a YAML document'),
    (f'qfa_node:\n  ros__parameters: [{SECRET}]\n', 'ros__parameters must be a mapping'),
])
def test_a_bad_parameter_file_is_refused_in_one_line_without_quoting_it(tmp_path, capsys,
                                                                        content, expected):
    config = tmp_path / 'qfa.yaml'
    config.write_text(content)
    assert report.main(['imu-yaml', str(config)]) == 1
    err = capsys.readouterr().err
    assert expected in err and err.count('\n') == 1 and 'hunter2' not in err, err


def test_an_unwritable_out_is_one_line(tmp_path, capsys):
    """Before: a FileNotFoundError or IsADirectoryError traceback."""
    for out in (tmp_path / 'missing' / 'imu.yaml', tmp_path):
        assert report.main(['imu-yaml', str(ROOT / 'config' / 'qfa.yaml'), '--out',
                            str(out)]) == 1
        err = capsys.readouterr().err
        assert err.startswith(f'qfa-report: --out {out}: ') and err.count('\n') == 1


def test_the_node_reads_its_imu_yaml_once_bounded_and_emulates_it(tmp_path):
    source = tmp_path / 'imu.yaml'
    source.write_text(KALIBR_YAML)
    values = defaults(**{'noise.imu_yaml': str(source)})
    spec = {spec.name: spec for spec in PARAMETERS}['noise.imu_yaml']
    assert spec.read_only and spec.default == ''
    assert load_imu_noise(defaults()) is None
    noise = load_imu_noise(values)
    source.unlink()  # what the node runs is what it read at start
    config = triad_config(values, imu_noise=noise)
    assert config_figures(config) == pytest.approx(noise)
    assert config.noise.bias_instability == 0 and config.gyro.bias_instability == 0
    assert config.noise.adc_noise == 4.0  # the QFA loop stays
    # An ideal sensor with the file's noise, nothing else.
    ideal = triad_config(defaults(**{'sensor.error_profile': 'ideal'}), imu_noise=noise)
    assert ideal.noise.noise_density == 2.0e-5 and ideal.noise.random_walk == 1.0e-4
    for path, expected in ((tmp_path / 'missing', 'cannot open'),
                           ('/proc/self/environ', 'on the kernel file system proc'),
                           (tmp_path, 'not a regular file')):
        with pytest.raises(ValueError) as caught:
            load_imu_noise(defaults(**{'noise.imu_yaml': str(path)}))
        assert str(caught.value).startswith('noise.imu_yaml: ') and expected in str(
            caught.value), caught.value
    large = tmp_path / 'large.yaml'
    large.write_text(KALIBR_YAML + '#' * (64 * 1024))
    with pytest.raises(ValueError, match='more than the 65536'):
        load_imu_noise(defaults(**{'noise.imu_yaml': str(large)}))
    # Below what the loop's ADC leaves on its own: refused, with the floor.
    quiet = ImuNoiseFigures(1e-9, 0.0, 1e-7, 0.0)
    with pytest.raises(ValueError, match=r'noise.imu_yaml: accelerometer_noise_density is '
                                         r'below .* \(2.37e-09'):
        triad_config(defaults(), imu_noise=quiet)
