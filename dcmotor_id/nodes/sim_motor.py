"""
``sim_motor``: the node of a DC motor drive simulated in real time (exact ZOH hybrid model).

Publishes the measured ``voltage`` [V], ``current`` [A] and ``speed`` [rad/s] of every sample
at ``sample_rate_hz``, either as three ``std_msgs/msg/Float64`` topics (``transport:
float64``: the n-th message of each topic is sample n, published voltage, current, speed in
that order) or as batches on ``samples`` (``transport: batch``: ``std_msgs/msg/
Float64MultiArray`` laid out as :mod:`dcmotor_id.formats.batch`, ``t`` in seconds since the
simulation started), which is what makes 10 kHz and more practical. The voltage comes from
the node's excitation generator, or from the ``voltage_command`` topic when
``use_voltage_command`` is true (the last command is held). Defaults: the paper's motor 2.
The ``effects`` parameter switches on effects of the vocabulary of
:mod:`dcmotor_id.identification.effects`
(e.g. ``load_torque:torque_Nm=0.3;current_offset:offset_A=0.05``), simulated sample by sample.
The ``schedule`` parameter changes the motor while it runs
(:mod:`dcmotor_id.streaming.online.schedule`,
e.g. ``Ra:+25%:ramp:10:70;b:+50%:step:30;load_torque:+0.5:step:90``; parameters held over
each timer tick), to show online tracking and change alarms.
"""

from __future__ import annotations

from array import array
from typing import Any, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension, MultiArrayLayout

from dcmotor_id.core.model import MotorParameters, PAPER_MOTORS, UNITS
from dcmotor_id.formats.batch import batch_message as build_batch, BatchTypes
from dcmotor_id.identification.effects import parse_effect
from dcmotor_id.nodes.common import declare, guard_parameters, own_parameters, run, sample_qos
from dcmotor_id.simulation import motor_forcing, motor_system, MotorStepper
from dcmotor_id.simulation.excitation import EXCITATION_KINDS, make_excitation
from dcmotor_id.streaming.online.schedule import parse_schedule

TRANSPORTS = ('float64', 'batch')


class SimMotor(Node):
    """Real-time simulated drive publishing voltage, current and speed."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('sim_motor', **kwargs)
        self.params = self._declare_motor()
        signal, excitation = self._declare_excitation()
        self._declare_outputs()
        effects_text = declare(self, 'effects', '',
                               "effects to simulate: 'NAME:param=value,...' joined by ';'")
        schedule = declare(self, 'schedule', '', 'parameter changes over time: '
                           '"NAME:CHANGE:step:AT" or "NAME:CHANGE:ramp:FROM:TO" joined by ";"')
        depth = declare(self, 'qos_depth', 5000, 'history depth of the sample topics',
                        low=1)
        reliability = declare(self, 'qos_reliability', 'reliable',
                              'reliable or best_effort', choices=('reliable', 'best_effort'))

        self.sample_period_s = 1.0 / self.sample_rate_hz
        period = excitation.pop('period')
        _, pattern = make_excitation(signal, period, self.sample_period_s, **excitation)
        self._pattern = pattern
        self._system = motor_system(self.params)
        self._state = np.zeros(2)
        self.effects = parse_effects(effects_text)
        self.schedule, self._base, self._load = parse_schedule(schedule), self.params, 0.0
        self._stepper = None
        if self.effects:
            self._stepper = MotorStepper(self.params, self.sample_period_s, effects=self.effects)
            offset = self._stepper.effects.current_offset_A if self._stepper.effects else 0.0
            self._measured = (offset, 0.0)
        self._command = 0.0
        self._rng = np.random.default_rng(excitation['seed'])
        self.published = 0
        self.overflows = 0
        self._create_interfaces(sample_qos(depth, reliability))
        guard_parameters(self, own_parameters(self))  # all read here, at start-up
        self.get_logger().info(
            f'simulating {self.params} at {self.sample_rate_hz:g} Hz, {signal} excitation, '
            f'transport {self.transport}')

    def _declare_motor(self) -> MotorParameters:
        """Declare the true parameters (paper motor 2 by default); refuse non-positive ones."""
        truth = PAPER_MOTORS['paper2']
        values = {name: declare(self, name, float(getattr(truth, name)),
                                f'true {name} of the simulated motor [{UNITS[name]}]',
                                low=0.0)
                  for name in ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')}
        params = MotorParameters(**values)
        if min(params.Ra, params.La, params.CPhi, params.J) <= 0:
            raise ValueError('Ra, La, CPhi and J must be positive')
        return params

    def _declare_excitation(self) -> tuple[str, dict[str, Any]]:
        """Declare the rates and the generator; return its kind and make_excitation options."""
        self.sample_rate_hz = declare(self, 'sample_rate_hz', 1000.0,
                                      'samples per second published', low=1.0, high=1e6)
        self.publish_rate_hz = declare(
            self, 'publish_rate_hz', 100.0, 'timer rate; each tick publishes every sample '
            'due since the last one', low=1.0, high=1e4)
        signal = declare(self, 'signal', 'paper', 'excitation voltage generator',
                         choices=EXCITATION_KINDS)
        amplitude = declare(self, 'amplitude_v', 0.0,
                            'excitation amplitude [V]; 0 = the signal default', low=0.0)
        frequency = declare(self, 'frequency_hz', 0.0,
                            'excitation frequency [Hz]; 0 = the signal default', low=0.0)
        period = declare(self, 'excitation_period_s', 8.0,
                         'length of the generated excitation pattern, repeated [s]',
                         low=1e-3)
        offset = declare(self, 'offset_v', 0.0, 'constant added to the excitation [V]')
        seed = declare(self, 'seed', 0, 'seed of the PRBS and of the sensor noise')
        return signal, {'period': period, 'amplitude_v': amplitude or None,
                        'frequency_hz': frequency or None, 'offset_v': offset, 'seed': seed}

    def _declare_outputs(self) -> None:
        """Declare the drive's input, the sensor noise and the transport of the samples."""
        self.use_command = declare(self, 'use_voltage_command', False,
                                   'drive with the last voltage_command instead of the '
                                   'generator')
        self.noise_current = declare(self, 'noise_current_a', 0.01,
                                     'std of white noise on the published current [A]',
                                     low=0.0)
        self.noise_speed = declare(self, 'noise_speed_rad_s', 0.02,
                                   'std of white noise on the published speed [rad/s]',
                                   low=0.0)
        self.transport = declare(self, 'transport', 'float64',
                                 'float64: three Float64 topics; batch: Float64MultiArray '
                                 'on samples', choices=TRANSPORTS)
        self.batch_samples = declare(self, 'batch_samples', 0,
                                     'samples per batch message; 0 = all due at a tick',
                                     low=0)

    def _create_interfaces(self, qos: Any) -> None:
        """Create the sample publishers, the command subscription, the timers, diagnostics."""
        if self.transport == 'float64':
            self._sample_publishers = [self.create_publisher(Float64, topic, qos)
                                       for topic in ('voltage', 'current', 'speed')]
        else:
            self._batch_publisher = self.create_publisher(Float64MultiArray, 'samples', qos)
        self.create_subscription(Float64, 'voltage_command', self._on_command, 10)
        self._start_ns = None
        self._timer = self.create_timer(1.0 / self.publish_rate_hz, self._tick)
        self._diagnostics = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_timer(1.0, self._report)

    def _on_command(self, message):
        if np.isfinite(message.data):
            self._command = float(message.data)
        else:
            self.get_logger().warning('voltage_command is not finite; ignored',
                                      throttle_duration_sec=5.0)

    def _tick(self):
        now = self.get_clock().now().nanoseconds
        if self._start_ns is None:
            self._start_ns = now
        due = int((now - self._start_ns) * 1e-9 * self.sample_rate_hz) + 1 - self.published
        if due <= 0:
            return
        # after a stall, catch up in bursts of at most a quarter second of samples
        self.publish_samples(min(due, int(0.25 * self.sample_rate_hz) + 1))

    def _report(self):
        """Publish how many samples went out and how far behind real time the drive is."""
        behind_s = 0.0
        if self._start_ns is not None:
            elapsed_s = (self.get_clock().now().nanoseconds - self._start_ns) * 1e-9
            behind_s = max(0.0, elapsed_s - self.published * self.sample_period_s)
        status = DiagnosticStatus(
            level=DiagnosticStatus.OK if behind_s < 0.5 else DiagnosticStatus.WARN,
            name=f'{self.get_name()}: drive', hardware_id=self.get_fully_qualified_name(),
            message='real time' if behind_s < 0.5 else f'{behind_s:.1f} s behind real time')
        status.values = [KeyValue(key='published', value=str(self.published)),
                         KeyValue(key='behind_s', value=f'{behind_s:.3f}'),
                         KeyValue(key='sample_rate_hz', value=repr(self.sample_rate_hz))]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)

    def publish_samples(self, count: int) -> None:
        """Simulate and publish the next ``count`` samples."""
        index = self.published + np.arange(count)
        if self.use_command:
            voltage = np.full(count, self._command)
        else:
            voltage = self._pattern[index % self._pattern.size]
        if self.schedule:
            self._follow_schedule(self.published * self.sample_period_s)
        if self._stepper is None:
            load = np.full(count, -self._load)
            forcing = motor_forcing(self.params, voltage, extra_torque=load)
            states = self._system.simulate(forcing, self._state, self.sample_period_s)
            self._state = states[-1].copy()
            measured = states[:-1]
        else:
            # Effects: what the sensors read at t_k, then one step of the effects model.
            measured = np.empty((count, 2))
            for k, u in enumerate(voltage.tolist()):
                measured[k] = self._measured
                self._measured = self._stepper.step(u, extra_torque=-self._load)
        current = measured[:, 0] + self._rng.normal(0.0, self.noise_current, count) \
            if self.noise_current > 0 else measured[:, 0].copy()
        speed = measured[:, 1] + self._rng.normal(0.0, self.noise_speed, count) \
            if self.noise_speed > 0 else measured[:, 1].copy()
        if self.transport == 'float64':
            volt_pub, curr_pub, speed_pub = self._sample_publishers
            for u, i, w in zip(voltage.tolist(), current.tolist(), speed.tolist()):
                volt_pub.publish(Float64(data=u))
                curr_pub.publish(Float64(data=i))
                speed_pub.publish(Float64(data=w))
        else:
            size = self.batch_samples or count
            for start in range(0, count, size):
                part = slice(start, min(start + size, count))
                self._batch_publisher.publish(batch_message(
                    index[part] * self.sample_period_s, voltage[part], current[part],
                    speed[part]))
        self.published += count
        self._check_state(float(voltage[-1]) if count else 0.0)

    def _check_state(self, voltage: float) -> None:
        """Put the simulated motor back at rest when its state overflowed (say so)."""
        state = self._state if self._stepper is None else np.asarray(self._measured)
        if np.all(np.isfinite(state)):
            return
        self.get_logger().error(f'the simulated state overflowed (voltage {voltage:.4g} V): '
                                'the motor is put back at rest', throttle_duration_sec=5.0)
        self.overflows += 1
        self._state = np.zeros(2)
        if self._stepper is not None:
            self._stepper = MotorStepper(self.params, self.sample_period_s,
                                         effects=self.effects)
            offset = self._stepper.effects.current_offset_A if self._stepper.effects else 0.0
            self._measured = (offset, 0.0)

    def _follow_schedule(self, time_s: float) -> None:
        """Set the motor and the load torque (opposing positive rotation) of ``time_s``."""
        params, self._load = self.schedule.at(self._base, time_s)
        if params == self.params:
            return
        self.params = params
        self._system = motor_system(params)
        if self._stepper is not None:
            old = self._stepper
            self._stepper = MotorStepper(params, self.sample_period_s, old.state, self.effects)
            for name in ('angle_rad', 'time_s', '_current_queue', '_speed_queue'):
                if hasattr(old, name):
                    setattr(self._stepper, name, getattr(old, name))


def parse_effects(text: str) -> list:
    """
    Parse the ``effects`` parameter into vocabulary effects (empty text: none).

    Raises ``ValueError`` naming the bad entry and the vocabulary.
    """
    effects = []
    for entry in filter(None, (part.strip() for part in text.split(';'))):
        try:
            effects.append(parse_effect(entry))
        except (TypeError, ValueError) as error:
            raise ValueError(f'parameter effects: {entry!r}: {error}') from None
    return effects


#: The rclpy classes of a batch (rclpy takes the data as an ``array('d')``).
RCLPY_BATCH = BatchTypes(message=Float64MultiArray, layout=MultiArrayLayout,
                         dimension=MultiArrayDimension,
                         pack=lambda values: array('d', values.tobytes()))


def batch_message(time_s: np.ndarray, voltage: np.ndarray, current: np.ndarray,
                  speed: np.ndarray) -> Float64MultiArray:
    """Pack samples into a Float64MultiArray in the documented batch layout."""
    return build_batch(RCLPY_BATCH, time_s, voltage, current, speed)


def main(args: Optional[list[str]] = None) -> int:
    """Run the ``sim_motor`` node."""
    return run(SimMotor, args)


if __name__ == '__main__':
    raise SystemExit(main())
