"""
The batched-samples wire layout: one ``std_msgs/msg/Float64MultiArray`` carries many samples.

``layout.dim[0]`` is labelled :data:`BATCH_LABEL` with size 4 (the channels) and
``layout.dim[1]`` is labelled ``sample`` with the number of samples; the data hold ``t`` [s]
of every sample, then every voltage [V], current [A] and speed [rad/s]. The same layout is
built here for rclpy messages (``sim_motor``) and rosbags messages (bag writing), and decoded
here for both (the identifier node, the bag reader).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Callable, NamedTuple

import numpy as np

from dcmotor_id.core.errors import InputDataError

#: Message type of a batch.
BATCH_TYPE = 'std_msgs/msg/Float64MultiArray'
#: Label of the first dimension of a batched ``std_msgs/msg/Float64MultiArray`` sample message:
#: the data hold ``t`` [s] of every sample, then every voltage [V], current [A], speed [rad/s].
BATCH_LABEL = 't,voltage,current,speed'
#: Channels carried by a batch, in order.
BATCH_CHANNELS = ('t', 'voltage', 'current', 'speed')


class BatchTypes(NamedTuple):
    """
    The message classes a batch is built from, for one message library.

    Attributes
    ----------
    message : callable
        ``Float64MultiArray(layout=..., data=...)``.
    layout : callable
        ``MultiArrayLayout(dim=..., data_offset=...)``.
    dimension : callable
        ``MultiArrayDimension(label=..., size=..., stride=...)``.
    pack : callable
        Turns the float64 data array into what ``message`` accepts as ``data`` (rclpy wants an
        ``array('d')``, rosbags a numpy array).

    """

    message: Callable[..., Any]
    layout: Callable[..., Any]
    dimension: Callable[..., Any]
    pack: Callable[[np.ndarray], Any] = np.asarray


def encode_batch(time_s: Sequence[float] | np.ndarray, voltage: Sequence[float] | np.ndarray,
                 current: Sequence[float] | np.ndarray,
                 speed: Sequence[float] | np.ndarray) -> np.ndarray:
    """Lay out samples as the data of a batched Float64MultiArray (see :data:`BATCH_LABEL`)."""
    return np.concatenate([np.asarray(values, dtype=float) for values in
                           (time_s, voltage, current, speed)])


def batch_message(types: BatchTypes, time_s: np.ndarray, voltage: np.ndarray,
                  current: np.ndarray, speed: np.ndarray) -> Any:
    """
    Build one batch message of the given message library in the documented layout.

    Parameters
    ----------
    types : BatchTypes
        Message classes of rclpy or of a rosbags typestore.
    time_s, voltage, current, speed : numpy.ndarray
        The samples: time [s], voltage [V], current [A], speed [rad/s], all of one length.

    Returns
    -------
    object
        A ``Float64MultiArray`` of ``types``.

    """
    count = len(time_s)
    channels = len(BATCH_CHANNELS)
    layout = types.layout(dim=[types.dimension(label=BATCH_LABEL, size=channels,
                                               stride=channels * count),
                               types.dimension(label='sample', size=count, stride=count)],
                          data_offset=0)
    return types.message(layout=layout,
                         data=types.pack(encode_batch(time_s, voltage, current, speed)))


def decode_batch(labels: Sequence[str], sizes: Sequence[int], data: Any) -> np.ndarray:
    """
    Split the data of a batched Float64MultiArray into ``t, voltage, current, speed``.

    Returns
    -------
    numpy.ndarray
        Shape ``(4, samples)``: rows ``t`` [s], voltage [V], current [A], speed [rad/s].

    Raises
    ------
    InputDataError
        When the layout is not the documented one, or the times do not increase (samples
        out of order would be fitted as a motor running backwards in time).

    """
    data = np.asarray(data, dtype=float)
    if len(labels) < 1 or labels[0] != BATCH_LABEL or sizes[0] != len(BATCH_CHANNELS):
        raise InputDataError(
            f'batched samples need layout.dim[0] labelled {BATCH_LABEL!r} with size '
            f'{len(BATCH_CHANNELS)} (got labels {list(labels)}, sizes {list(sizes)})')
    if data.size % len(BATCH_CHANNELS):
        raise InputDataError(f'batched samples: {data.size} values is not a multiple of '
                             f'{len(BATCH_CHANNELS)} channels')
    block = data.reshape(len(BATCH_CHANNELS), -1)
    if len(sizes) > 1 and sizes[1] != block.shape[1]:
        raise InputDataError(f'batched samples: layout.dim[1] says {sizes[1]} samples, the '
                             f'data hold {block.shape[1]}')
    times = block[0][np.isfinite(block[0])]
    backwards = np.flatnonzero(np.diff(times) <= 0)
    if backwards.size:
        row = int(backwards[0]) + 1
        raise InputDataError(f'batched samples: the times do not increase at sample {row} '
                             f'(t = {times[row]:.9g} s after {times[row - 1]:.9g} s); a batch '
                             'holds its samples in time order')
    return block


def decode_batch_message(message: Any) -> np.ndarray:
    """
    Decode a batch message of rclpy or rosbags (anything with ``layout.dim`` and ``data``).

    Returns and raises as :func:`decode_batch`.
    """
    dims = message.layout.dim
    data = message.data
    if not isinstance(data, np.ndarray):
        data = np.frombuffer(data, dtype=float)
    return decode_batch([dim.label for dim in dims], [dim.size for dim in dims], data)
