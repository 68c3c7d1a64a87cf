"""
How real drives publish their samples: the messages, their stamps and their order (no ROS).

A simulated record is sampled on a perfect grid; a robot's drive publishes it otherwise.
:func:`drive_messages` turns a record into the messages a drive would publish, each with the
time it is published, its stamp and its DDS sequence number:

* ``stamps='grid'``: header stamps at the sample instants with a uniform jitter of up to
  ``jitter`` sample periods; ``stamps='now'``: stamped with the publication time;
* ``burst_s`` > 0: the publishing loop (one for both topics) sleeps that long and then
  publishes every sample due at once (as a timer-driven control loop catches up under
  load); else each sample is published when due (plus a small random delay);
* the voltage on a topic of its own, at ``voltage_rate`` times the joint states' rate (each
  voltage held for that many of its samples), stamped with a header like the joint states or,
  with ``voltage_stamp='publish'``, only by its publication time (DDS source time).

The node tests and ``bench/bench_robot_topics.py`` publish these messages with rclpy; the
alignment tests feed them straight to :class:`~dcmotor_id.formats.regrid.StampRegridder`.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np

__all__ = ['DriveMessage', 'drive_messages']


class DriveMessage(NamedTuple):
    """One published message."""

    publish_ns: int           #: when it is published [ns]
    topic: str                #: ``joint_states`` (current, speed) or ``voltage``
    stamp_ns: int             #: its header stamp, or its publication time without a header
    sequence: int             #: its DDS publication sequence number (from 1, per topic)
    values: tuple             #: (current, speed) or (voltage,)
    sample_ns: int = 0        #: the instant of its sample [ns]


def _publish_times(true_ns: np.ndarray, burst_s: float, period_ns: float,
                   rng: np.random.Generator, phase: float) -> np.ndarray:
    """When each sample is published: at the next wake-up of a bursty loop, or when due."""
    if burst_s > 0:
        burst_ns = burst_s * 1e9
        phase = phase * burst_ns
        wake = np.ceil((true_ns - phase) / burst_ns) * burst_ns + phase
        # the burst's messages go out in sample order, a few microseconds each (the whole
        # burst in a thousandth of its span)
        return (wake + (true_ns - wake + burst_ns) * 1e-3).astype(np.int64)
    return (true_ns + rng.uniform(0.02, 0.2, true_ns.size) * period_ns).astype(np.int64)


def drive_messages(voltage: np.ndarray, current: np.ndarray, speed: np.ndarray,
                   rate_hz: float, *, stamps: str = 'grid', jitter: float = 0.0,
                   burst_s: float = 0.0, voltage_rate: int = 1,
                   voltage_stamp: str = 'header', start_ns: int = 1_700_000_000_000_000_000,
                   seed: Optional[int] = 0) -> list[DriveMessage]:
    """
    Return the messages a drive publishes for the samples given, in publication order.

    Parameters
    ----------
    voltage, current, speed : numpy.ndarray
        The samples at ``rate_hz`` (the voltage held over each sample period).
    rate_hz : float
        The joint states' rate [Hz].
    stamps : str
        ``'grid'`` (the sample instant, with ``jitter``) or ``'now'`` (publication time).
    jitter : float
        Largest stamp error of ``'grid'`` stamps [sample periods] (uniform).
    burst_s : float
        The publishing loop's sleep [s] (0: each sample published when due).
    voltage_rate : int
        The voltage topic's rate over the joint states' (its samples repeat each value).
    voltage_stamp : str
        ``'header'`` (stamped as the joint states) or ``'publish'`` (publication time).
    start_ns : int
        The time of the first sample [ns].
    seed : int or None
        Seed of the jitter and the publication delays.

    """
    rng = np.random.default_rng(seed)
    period_ns = 1e9 / rate_hz
    count = len(current)
    true_ns = start_ns + np.arange(count) * period_ns
    messages = []
    phase = rng.uniform()  # one loop publishes both topics: the same wake-ups
    for topic, times_ns, rows in (
            ('joint_states', true_ns, list(zip(current, speed))),
            ('voltage', start_ns + np.arange(count * voltage_rate) * period_ns / voltage_rate,
             [(float(u),) for u in np.repeat(voltage, voltage_rate)])):
        published = _publish_times(times_ns, burst_s, period_ns / (
            voltage_rate if topic == 'voltage' else 1), rng, phase)
        if topic == 'voltage' and voltage_stamp == 'publish':
            stamped = published
        elif stamps == 'now':
            stamped = published
        else:
            stamped = (times_ns + rng.uniform(-jitter, jitter, times_ns.size) *
                       period_ns).astype(np.int64)
        for number, (publish_ns, stamp_ns, row, sample_ns) in enumerate(
                zip(published, stamped, rows, times_ns)):
            messages.append(DriveMessage(int(publish_ns), topic, int(stamp_ns), number + 1,
                                         tuple(map(float, row)), int(sample_ns)))
    messages.sort(key=lambda message: message.publish_ns)
    return messages
