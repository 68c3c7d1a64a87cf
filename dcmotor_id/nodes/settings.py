"""The identifier node's parameters as one typed dataclass: names, defaults, ranges, texts."""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Optional, Sequence

from dcmotor_id.identification.identify import METHODS
from dcmotor_id.streaming.online.base import METHODS as ONLINE_METHODS

INPUTS = ('float64', 'batch', 'joint_state', 'dynamic_joint_state')


def parameter(default: Any, description: str, low: Optional[float] = None,
              high: Optional[float] = None, choices: Optional[Sequence[str]] = None,
              dynamic_typing: bool = False) -> Any:
    """
    Describe one ROS parameter: its default, description, range and choices.

    ``dynamic_typing``: a value of another type is taken (not refused by rclpy, which would
    stop the node), for the node to check it and say what is wrong.
    """
    metadata = {'description': description, 'low': low, 'high': high, 'choices': choices}
    if dynamic_typing:
        metadata['dynamic_typing'] = True
    return field(default=default, metadata=metadata)


def check_structure_bootstrap(value: Any) -> int:
    """
    Return ``structure_bootstrap`` as an int; ValueError naming the parameter when unusable.

    0 (off) or a whole number of resamples from 2 to
    :data:`~dcmotor_id.identification.structure_uncertainty.MAX_RESAMPLES`, as
    ``identify --structure-bootstrap N`` takes.
    """
    from dcmotor_id.core.errors import InputDataError
    from dcmotor_id.identification.structure_uncertainty import check_resamples

    try:
        if isinstance(value, (bool, str)):
            raise InputDataError('not a number')
        return check_resamples(value)
    except InputDataError:
        from dcmotor_id.identification.structure_uncertainty import MAX_RESAMPLES
        raise ValueError(f'parameter structure_bootstrap = {value!r} refused: give a whole '
                         f'number of noise resamples from 2 to {MAX_RESAMPLES} (20 is a good '
                         'start), or 0 to leave the structure choice out of the standard '
                         'errors') from None


@dataclass(frozen=True)
class IdentifierSettings:
    """The settings of the ``identifier`` node, one field per ROS parameter."""

    input: str = parameter(  # noqa: A003
        'float64', 'float64, batch, joint_state or dynamic_joint_state', choices=INPUTS)
    sample_rate_hz: float = parameter(1000.0, 'sample rate of the drive [Hz]', 1.0, 1e6)
    align_by: str = parameter('sequence', 'float64 input: sequence (DDS publication sequence '
                              'number) or timestamp (DDS source timestamp)',
                              choices=('sequence', 'timestamp'))
    max_delay_s: float = parameter(0.5, 'how long a sample waits for a late channel before it '
                                   'is counted as lost [s]', 0.0)
    qos_depth: int = parameter(5000, 'history depth of the sample topics', 1)
    qos_reliability: str = parameter('reliable', 'reliable or best_effort',
                                     choices=('reliable', 'best_effort'))
    joint_name: str = parameter('', 'joint_state and dynamic_joint_state input: joint to use '
                                '("" = the first)')
    current_interface: str = parameter('current', "dynamic_joint_state input: the joint's "
                                       'state interface of the armature current [A]')
    voltage_interface: str = parameter('voltage', "dynamic_joint_state input: the joint's "
                                       'state interface of the armature voltage [V] ("" = '
                                       'the voltage topic, by its source timestamp)')
    speed_interface: str = parameter('velocity', "dynamic_joint_state input: the joint's "
                                     'state interface of the speed [rad/s]')
    effort_scale: float = parameter(1.0, 'joint_state input: current = effort_scale * effort '
                                    '[A]')
    torque_constant: float = parameter(0.0, '> 0: mechanical-only mode, torque = K current '
                                       '[N m/A]; identifies J, b, Mc without voltage', 0.0)
    window_s: float = parameter(10.0, 'length of a recorded window and of the data identified '
                                '[s]', 0.01)
    min_window_s: float = parameter(0.5, 'runs of samples shorter than this (cut by lost '
                                    'samples) are dropped, neither recorded nor identified '
                                    '[s]', 0.0)
    record: bool = parameter(True, 'write every window as an MCAP bag')
    record_dir: str = parameter('~/.ros/dcmotor_id/windows', 'directory of the window bags')
    disk_budget_mb: float = parameter(200.0, 'oldest windows are deleted beyond this [MiB]',
                                      0.0)
    min_free_mb: float = parameter(16.0, 'keep this much of the file system free [MiB]', 0.0)
    record_format: str = parameter('auto', 'float64 (three topics), batch (samples) or auto '
                                   '(as the input)', choices=('auto', 'float64', 'batch'))
    method: str = parameter('refined', 'identification method', choices=tuple(METHODS))
    compare_paper: bool = parameter(True, 'also run the paper method and report it')
    discover: bool = parameter(True, 'run the residual analysis / effect discovery')
    identify_in_subprocess: bool = parameter(True, 'fit in a separate process (keeps the '
                                             'executor at full rate during a fit)')
    identify_timeout_s: float = parameter(300.0, 'a fit still running after this is stopped '
                                          '(its process killed and replaced) and ~/identify '
                                          'answers with the timeout; 0 = no limit; needs '
                                          'identify_in_subprocess [s]', 0.0)
    structure_bootstrap: int = parameter(
        0, '~/identify: noise resamples that rerun the effect discovery so that the standard '
        'errors cover the choice of effects (as identify --structure-bootstrap N; each one '
        'costs about one more fit); 0 = off, else 2 to 1000; a bad value is refused and '
        'logged, the last good one is kept', dynamic_typing=True)
    online: bool = parameter(True, 'run the recursive online estimator')
    online_rate_hz: float = parameter(2.0, 'rate of ~/online_parameters [Hz]', 0.01, 1e3)
    online_memory_s: float = parameter(10.0, 'forgetting time constant of the online estimate '
                                       '[s]', 1e-3)
    online_converged_rel_stderr: float = parameter(0.05, 'relative standard error below '
                                                   'which the online estimate counts as '
                                                   'converged', 0.0)
    # --- online estimator (window or rls) and condition monitoring (issue 12)
    online_method: str = parameter('window', 'window: exact output-error refits of a sliding '
                                   'window (noise-consistent); rls: the old recursive least '
                                   'squares (biased by noise)', choices=ONLINE_METHODS)
    online_window_s: float = parameter(30.0, 'longest window of the online refits (it grows '
                                       'from the start up to this) [s]', 0.1)
    online_refit_interval_s: float = parameter(2.0, 'data time between online refits [s]', 0.01)
    online_cpu_budget: float = parameter(0.08, 'largest fraction of one core the online refits '
                                         'may take (the interval stretches)', 1e-3, 1.0)
    online_load_torque: bool = parameter(True, 'also estimate a constant load torque when the '
                                         'speed takes both signs')
    online_in_subprocess: bool = parameter(True, 'run the online refits in a process of their '
                                           'own')
    monitor: bool = parameter(True, 'detect parameter changes; alarms on /diagnostics')
    monitor_baseline: str = parameter('auto', 'auto (nominal_* if given, else the last '
                                      '~/identify, else the first converged online estimate), '
                                      'nominal, identify or online',
                                      choices=('auto', 'nominal', 'identify', 'online'))
    monitor_warn_pct: float = parameter(5.0, 'smallest change reported as WARN [%]', 0.0)
    monitor_error_pct: float = parameter(15.0, 'smallest change reported as ERROR [%]', 0.0)
    monitor_threshold_sigma: float = parameter(5.0, 'a change must exceed this many standard '
                                               'deviations', 0.0)
    nominal_Ra: float = parameter(0.0, 'nominal Ra for the change baseline [Ohm]; 0 = none', 0.0)
    nominal_La: float = parameter(0.0, 'nominal La [H]; 0 = none', 0.0)
    nominal_CPhi: float = parameter(0.0, 'nominal CPhi [V s]; 0 = none', 0.0)
    nominal_J: float = parameter(0.0, 'nominal J [kg m^2]; 0 = none', 0.0)
    nominal_b: float = parameter(0.0, 'nominal b [N m s/rad]', 0.0)
    nominal_Mc: float = parameter(0.0, 'nominal Mc [N m]', 0.0)
    stream_timeout_s: float = parameter(1.0, 'a topic silent this long counts as stopped [s]',
                                        0.01)
    process_rate_hz: float = parameter(50.0, 'rate at which received samples are aligned '
                                       '[Hz]', 1.0)


#: Most samples a window may hold (the node keeps about three windows of four columns).
MAX_WINDOW_SAMPLES = 1e7


def check_settings(settings: IdentifierSettings) -> None:
    """
    Refuse at start-up settings that each pass their own range but cannot work together.

    A window beyond :data:`MAX_WINDOW_SAMPLES` (memory), ``min_window_s`` above
    ``window_s`` (no window is ever long enough), a non-finite
    ``effort_scale``, and a ``record_dir`` that cannot be written while ``record`` is on (the
    node would run without its recording).  ValueError naming the parameter.
    """
    from dcmotor_id.nodes.common import check_writable_directory

    samples = settings.window_s * settings.sample_rate_hz
    if samples > MAX_WINDOW_SAMPLES:
        raise ValueError(f'parameter window_s = {settings.window_s:g} s is {samples:.3g} samples '
                         f'at sample_rate_hz {settings.sample_rate_hz:g}: the node keeps about '
                         f'three windows in memory; give at most {MAX_WINDOW_SAMPLES:.0e} '
                         f'samples (window_s <= {MAX_WINDOW_SAMPLES / settings.sample_rate_hz:g}'
                         ' s at this rate)')
    if settings.min_window_s > settings.window_s:
        raise ValueError(f'parameter min_window_s = {settings.min_window_s:g} s is longer than '
                         f'window_s = {settings.window_s:g} s: no window could be kept; give a '
                         'min_window_s at most window_s')
    if not math.isfinite(settings.effort_scale) or settings.effort_scale == 0:
        raise ValueError(f'parameter effort_scale = {settings.effort_scale!r}: give a finite, '
                         'non-zero factor [A per unit of effort]')
    if settings.record:
        check_writable_directory(settings.record_dir, 'record_dir')
