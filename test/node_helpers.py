"""Run the QFA node as a subprocess and talk to it through real rclpy clients."""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState
import node_fork
import numpy as np
from rcl_interfaces.srv import GetParameters, SetParameters
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from qfa_ros.model.constants import MICRO_G
from qfa_ros.model.drawn_unit import draw_unit
from qfa_ros.ros.bounds import LARGEST_CHAMBER, LARGEST_FEEDBACK, LARGEST_FORWARD
from qfa_ros.ros.distro import ros_distribution, SUPPORTED_DISTRIBUTIONS
from qfa_ros.ros.fastdds import use_shipped_fastdds_profile
from qfa_ros.ros.parameter_table import PARAMETERS

ROOT = Path(__file__).resolve().parents[1]
PROFILES_FILE = ROOT / 'config' / 'fastdds_discovery.xml'
NODE = 'qfa_node'
QUERY_RESEND_S = 10.0
"""A query (state, transitions, parameters) unanswered this long is sent again [s]: its
response may have been dropped (:meth:`Client.call`); a node held up on a busy machine
answers both."""

# The test process is a long-running participant too: the discovery profile (under the
# name this distribution's Fast DDS reads) and the localhost-only discovery apply to it as
# to the node.
os.environ.setdefault('FASTDDS_DEFAULT_PROFILES_FILE', str(PROFILES_FILE))
use_shipped_fastdds_profile()
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

OPERATOR_ONLY = frozenset({
    'output_dir', 'state_file', 'state.fresh', 'noise.imu_yaml', 'input.trajectory_file',
    'sample_rate_hz', 'loop_rate_hz', 'temperature_rate_hz', 'diagnostics_rate_hz',
    'truth.rate_hz', 'stream.lead_s', 'stream.batch_s', 'min_free_bytes',
    'input.stamp_window_s', 'recorder.keep_s', 'recorder.keep_bytes'})
"""What no participant sets in any state (issue 43): the parameters that name a file or a
directory the node reads or writes (``state.fresh`` decides whether the state file is
read), or bound its CPU, memory or disk, or the stall one message can cause, or how much of
the recordings is kept (a stranger could have them deleted). The tests'
own list (the boundary's, test_node_fuzz.py): a defect in the parameter table cannot move
their expectation; test_node_params.py checks that the table agrees."""

VENVS = {'kilted': ROOT / '.venv', 'jazzy': ROOT / '.venv-jazzy'}
"""The venv of each distribution (the Makefile's ``ROS_DISTRO``)."""

FRESH_INTERPRETERS = os.environ.get('QFA_TEST_FRESH_NODES', '') not in ('', '0')
"""Start every node as its command (``QFA_TEST_FRESH_NODES=1``), none forked
(:mod:`node_fork`): the suite as it was before the fork server, to compare."""

BOTH_DISTRIBUTIONS_ENV = 'QFA_TEST_BOTH_DISTRIBUTIONS'
"""Set (by .ci/run): a test that needs the other distribution's venv fails without it."""


def unit_output(specific_force, seed=1, temperature_c=25.0, bias_ug=(0.0, 0.0, 0.0)):
    """Return the static output (x, y, z) [m/s^2] of the node's drawn unit (``seed``).

    The model's loop input at a steady body temperature: ``(bias + a + k2 a^2)(1 + e(T))
    + b(T)`` with ``a = (I + M) f`` (:mod:`qfa_ros.model.drawn_unit`, :class:`QfaTriad`).
    """
    unit = draw_unit(seed)
    a = (np.eye(3) + np.asarray(unit.misalignment)) @ np.asarray(specific_force, dtype=float)
    sensed = np.asarray(bias_ug) * MICRO_G + a + np.asarray(unit.k2) * a * a
    return sensed * (1.0 + unit.scale_factor_error(temperature_c)) \
        + unit.zero_bias(temperature_c)


def largest_schedule_values():
    """Return the parameters of the largest schedules, from the one place that bounds them."""
    forward, feedback, chamber = LARGEST_FORWARD, LARGEST_FEEDBACK, LARGEST_CHAMBER
    values = {spec.name: spec.default for spec in PARAMETERS}
    values.update({
        'estimation.forward.points': forward.points, 'estimation.forward.step': forward.step,
        'estimation.forward.settle_s': forward.settle_s,
        'estimation.forward.average_s': forward.average_s,
        'estimation.forward.order': forward.order,
        'estimation.feedback.cycles': feedback.cycles,
        'estimation.feedback.settle_s': feedback.settle_s,
        'estimation.feedback.average_s': feedback.average_s,
        'estimation.feedback.order': feedback.order,
        'temperature_calibration.period_s': chamber.period_s,
        'temperature_calibration.cycles': chamber.cycles,
        'temperature_calibration.reference_steps': chamber.reference_steps})
    return values



def domain_id(tag):
    """
    Return a ROS domain id distinct per ``tag`` within this test run.

    ``QFA_TEST_DOMAINS=LOW-HIGH`` confines the ids (default 1-100), so that two test runs
    on one machine (two work trees) never share a domain. Tags get consecutive ids in the
    order they are first asked for (a hash of the tag collided in a range of 13), so the
    nodes of one test never share a domain while the run uses fewer tags than the range.
    Each pytest-xdist worker draws from its own part of the range (:func:`worker_domains`).
    """
    low, high = worker_domains()
    span = high - low + 1
    index = _DOMAIN_TAGS.setdefault(tag, len(_DOMAIN_TAGS))
    return low + (os.getpid() * 7 + index) % span


def worker_domains():
    """
    Return ``(low, high)``: the domain ids this test process may use.

    ``QFA_TEST_DOMAINS`` split into equal disjoint parts, one per pytest-xdist worker
    (``PYTEST_XDIST_WORKER`` ``gw<i>`` of ``PYTEST_XDIST_WORKER_COUNT``), so that two
    workers' nodes never meet; the whole range without xdist.
    """
    low, high = (int(part) for part in os.environ.get('QFA_TEST_DOMAINS', '1-100').split('-'))
    worker = os.environ.get('PYTEST_XDIST_WORKER')
    if worker:
        count = int(os.environ['PYTEST_XDIST_WORKER_COUNT'])
        share = (high - low + 1) // count
        if share < 1:
            raise ValueError(f'QFA_TEST_DOMAINS {low}-{high} has fewer ids than the '
                             f'{count} pytest-xdist workers')
        low += int(worker.removeprefix('gw')) * share
        high = low + share - 1
    return low, high


_DOMAIN_TAGS = {}
"""Tags in the order they were first given a domain in this test process."""


def other_distribution():
    """
    Return ``(distribution, python)``: the other supported distribution and its venv's python.

    Skips the test when that venv was not set up (``make setup ROS_DISTRO=...``), fails it
    instead with :data:`BOTH_DISTRIBUTIONS_ENV` set.
    """
    import pytest
    mine = ros_distribution()
    other = next(d for d in SUPPORTED_DISTRIBUTIONS if d != mine)
    python = VENVS[other] / 'bin' / 'python'
    if not python.exists():
        reason = (f'no {other} venv ({VENVS[other].name}): make setup ROS_DISTRO={other}; '
                  f'this is {mine}')
        if os.environ.get(BOTH_DISTRIBUTIONS_ENV):
            pytest.fail(reason)
        pytest.skip(reason)
    return other, python


def node_environment(domain, python=None):
    """
    Return the environment of a node process isolated on ``domain``.

    :param python: The python that runs the process. Another venv's gets an environment
        as its own shell would give it: without this venv's library path and the wheels'
        bootstrap guard (its bootstrap makes them), nor this venv's numba cache directory.
    """
    env = dict(os.environ)
    if python is not None and Path(python).parents[1] != Path(sys.prefix):
        for name in ('LD_LIBRARY_PATH', '_ROS_WHEELS_BOOTSTRAP_COMPLETE', 'NUMBA_CACHE_DIR'):
            env.pop(name, None)
    env['ROS_DOMAIN_ID'] = str(domain)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['FASTDDS_DEFAULT_PROFILES_FILE'] = str(PROFILES_FILE)
    env['PYTHONUNBUFFERED'] = '1'
    return env


class NodeProcess:
    """
    The node in its own process, its parameters given by a parameters file.

    :param domain: ROS domain id.
    :param directory: Where the parameters file and the log go.
    :param parameters: Parameter overrides.
    :param managed: Run ``qfa_lifecycle_node`` (the managed node, unconfigured at start).
    :param python: The python that runs it (default: this one).
    :param command: The command that starts it, before ``--ros-args`` (default:
        ``PYTHON -m qfa_ros.cli.node``, or the lifecycle node's ``main`` when ``managed``).
    :param env: Its environment (default: :func:`node_environment`).

    In a test (pytest sets ``PYTEST_CURRENT_TEST``) with neither ``command``, ``python``
    nor ``env``, the node is forked from a warmed fork server (:mod:`node_fork`) and runs
    the same ``main`` as the command would; otherwise (a bench: what it measures is the
    node as its users start it; ``QFA_TEST_FRESH_NODES=1``) the command starts it.
    """

    def __init__(self, domain, directory, parameters=None, name=NODE, managed=False,
                 python=None, command=None, env=None):
        self.domain = domain
        self.name = name
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        self.params_file = directory / f'{name}_{time.monotonic_ns()}.yaml'
        # JSON is YAML: no YAML writer needed, and doubles stay doubles.
        self.params_file.write_text(json.dumps(
            {name: {'ros__parameters': dict(parameters or {})}}))
        self.log_path = self.params_file.with_suffix('.log')
        self._log = open(self.log_path, 'w')
        arguments = ['--ros-args', '-r', f'__node:={name}', '--params-file',
                     str(self.params_file)]
        if (command is None and python is None and env is None and not FRESH_INTERPRETERS
                and 'PYTEST_CURRENT_TEST' in os.environ):
            self.process = node_fork.ForkedProcess(
                ['qfa_node', *arguments], node_environment(domain), ROOT, self.log_path,
                managed)
            return
        program = ['-c', 'import sys; from qfa_ros.cli.node import lifecycle_main; '
                   'sys.exit(lifecycle_main())'] if managed else ['-m', 'qfa_ros.cli.node']
        command = command or [python or sys.executable, *program]
        self.process = subprocess.Popen(
            [*command, *arguments], env=env or node_environment(domain, python),
            stdout=self._log, stderr=subprocess.STDOUT, cwd=ROOT)

    @property
    def pid(self):
        return self.process.pid

    def log(self):
        """Return what the node printed so far."""
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def wait(self, timeout=20.0):
        """Wait for the process to end by itself; return its exit status."""
        try:
            return self.process.wait(timeout)
        finally:
            self._log.close()

    def stop(self, signum=signal.SIGTERM, timeout=20.0):
        """Send ``signum`` and return the exit status."""
        if self.process.poll() is None:
            self.process.send_signal(signum)
        try:
            return self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
            raise
        finally:
            self._log.close()


class Client:
    """
    A test-side rclpy node in its own context on ``domain``.

    It spins rclpy's events executor (C++, one thread, as the single-threaded one):
    reading a 1 kHz ``imu/data_raw`` into :class:`ImuCollector` costs this process 0.29
    of a core with it, 0.67 with the ``SingleThreadedExecutor``, which builds its wait set
    in Python for every message (both distributions alike). It does not pass a message's
    info (a callback of two arguments): ``single=True`` spins the single-threaded one
    (``QFA_TEST_EXECUTOR=single``: every client).

    :param domain: ROS domain id.
    :param target: Name of the node under test.
    :param single: Spin the ``SingleThreadedExecutor``.
    """

    def __init__(self, domain, target=NODE, single=False):
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node('qfa_test_client', context=self.context)
        if single or os.environ.get('QFA_TEST_EXECUTOR') == 'single':
            self.executor = SingleThreadedExecutor(context=self.context)
        else:
            self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.target = target
        self.clients = {}

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def spin_until(self, predicate, timeout, what='condition', progress=None, limit=600.0):
        """
        Spin until ``predicate()`` is true; fail after ``timeout`` seconds.

        With ``progress`` (a callable), fail only after ``timeout`` seconds in which its
        value did not change, or after ``limit`` seconds: a test process starved by a busy
        machine may drain a backlog slower than it was published, yet get there.
        """
        started = time.monotonic()
        deadline = started + timeout
        last = progress() if progress else None
        while not predicate():
            now = time.monotonic()
            if progress is not None and progress() != last:
                last, deadline = progress(), now + timeout
            if now > deadline or now > started + limit:
                raise TimeoutError(f'timed out after {now - started:.0f} s waiting for {what}')
            self.executor.spin_once(timeout_sec=0.05)

    def spin_for(self, seconds):
        """Spin for ``seconds`` (a measurement window, not a wait for a match)."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))

    def subscribe(self, msg_type, topic, callback, depth=1000, latched=False, qos=None):
        """Subscribe reliably (``depth``), latched, or with the profile ``qos`` if given."""
        if qos is not None:
            return self.node.create_subscription(msg_type, topic, callback, qos)
        qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
        if latched:
            qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        return self.node.create_subscription(msg_type, topic, callback, qos)

    def client(self, srv_type, name):
        if name not in self.clients:
            self.clients[name] = self.node.create_client(srv_type, name)
        return self.clients[name]

    def call_async(self, srv_type, name, request, timeout=30.0):
        """Send a request once the service is there; return the future."""
        client = self.client(srv_type, name)
        self.spin_until(client.service_is_ready, timeout, f'service {name}')
        return client.call_async(request)

    def call(self, srv_type, name, request, timeout=60.0, resend_s=None):
        """
        Call a service and return the response.

        With ``resend_s`` (a query, safe to repeat) the request goes again after that long
        without an answer, until ``timeout``: Fast DDS drops a response to a client whose
        reply reader the server has not discovered yet (the node logs "failed to send
        response (timeout)"; seen once in CI on Jazzy, the first query after a start).
        """
        deadline = time.monotonic() + timeout
        while True:
            future = self.call_async(srv_type, name, request, timeout)
            wait = max(0.0, deadline - time.monotonic())
            try:
                self.spin_until(future.done, wait if resend_s is None else min(resend_s, wait),
                                f'response of {name}')
                return future.result()
            except TimeoutError:
                self.client(srv_type, name).remove_pending_request(future)
                if resend_s is None or time.monotonic() >= deadline:
                    raise

    def set_parameters(self, values, timeout=30.0):
        """Set parameters of the node under test; return the results (one per parameter)."""
        request = SetParameters.Request()
        request.parameters = [Parameter(name, value=value).to_parameter_msg()
                              for name, value in values.items()]
        return self.call(SetParameters, f'/{self.target}/set_parameters', request,
                         timeout).results

    def get_parameters(self, names, timeout=30.0):
        request = GetParameters.Request(names=list(names))
        response = self.call(GetParameters, f'/{self.target}/get_parameters', request,
                             timeout, resend_s=QUERY_RESEND_S)
        return [parameter_value_to_python(value) for value in response.values]


class Lifecycle:
    """The lifecycle services of the node under test, called from ``client``'s participant."""

    def __init__(self, client):
        self.client = client
        self.answered_ns = None
        """This process's clock when the last ``change`` was answered [ns]."""

    def change(self, transition, timeout=90.0):
        """Ask for ``transition`` (a label or an id); return ``(success, state after)``."""
        request = ChangeState.Request()
        if isinstance(transition, str):
            request.transition.label = transition
        else:
            request.transition.id = transition
        response = self.client.call(ChangeState, f'/{self.client.target}/change_state', request,
                                    timeout)
        self.answered_ns = self.client.node.get_clock().now().nanoseconds
        return response.success, self.state()

    def state(self):
        """Return the label of the node's present state."""
        return self.client.call(GetState, f'/{self.client.target}/get_state',
                                GetState.Request(), resend_s=QUERY_RESEND_S).current_state.label

    def available(self):
        """Return the labels of the transitions available now."""
        response = self.client.call(GetAvailableTransitions,
                                    f'/{self.client.target}/get_available_transitions',
                                    GetAvailableTransitions.Request(), resend_s=QUERY_RESEND_S)
        return {item.transition.label for item in response.available_transitions}


class ImuCollector:
    """
    Collect ``imu/data_raw`` samples as (stamp ns, ax, ay, az) and whole messages.

    Reliable with ``depth`` unless ``qos`` (e.g. ``qos_profile_sensor_data``) is given.
    """

    def __init__(self, client, topic='imu/data_raw', depth=1000, qos=None):
        from sensor_msgs.msg import Imu
        self.samples = []
        self.after_ns = 0
        self.latest_ns = 0  # the stamp of the last sample received, kept or not
        self.last_message = None
        self.subscription = client.subscribe(Imu, topic, self.callback, depth, qos=qos)

    def callback(self, message):
        stamp = message.header.stamp
        stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        self.latest_ns = stamp_ns
        if stamp_ns < self.after_ns:
            return
        vector = message.linear_acceleration
        self.samples.append((stamp_ns, vector.x, vector.y, vector.z))
        self.last_message = message

    def clear(self, after_ns=0):
        """Forget the samples so far; from now on keep those stamped at ``after_ns`` or later."""
        self.samples = []
        self.after_ns = after_ns


def mean_accel(client, collector, count, timeout=30.0, settle_s=0.0):
    """
    Return the mean specific force (x, y, z) of ``count`` fresh samples.

    Fresh: stamped ``settle_s`` or more after this call (the node stamps with the same
    system clock), so neither samples still queued from before a change nor the loops'
    step response count, however late this process reads them. The node computes its
    output up to ``stream.lead_s`` (0.15 s) ahead: after a change, ``settle_s`` must exceed it.
    """
    collector.clear(time.time_ns() + int(settle_s * 1e9))
    client.spin_until(lambda: len(collector.samples) >= count, timeout, f'{count} samples',
                      progress=lambda: (collector.latest_ns, len(collector.samples)))
    samples = collector.samples[:count]
    return tuple(sum(s[k] for s in samples) / count for k in (1, 2, 3))


def counted_after(items, after_ns, stamp=lambda item: item):
    """
    Return a callable: how many of the growing list ``items`` are stamped at or after ``after_ns``.

    Each item is looked at once. A predicate that counted the whole list at every spin
    (once a message) cost a starved test process more than the stream it was counting.
    """
    looked = [0, 0]  # items looked at, of them stamped at or after after_ns

    def count():
        for item in items[looked[0]:]:
            looked[1] += stamp(item) >= after_ns
        looked[0] = len(items)
        return looked[1]
    return count


class RecordingNode:
    """What :class:`~qfa_ros.ros.recording.StreamRecording` uses of a node: name, logger, clock."""

    def get_name(self):
        return NODE

    def get_logger(self):
        return get_logger('test_recording')

    def get_clock(self):
        return SimpleNamespace(now=lambda: SimpleNamespace(nanoseconds=time.time_ns()))
