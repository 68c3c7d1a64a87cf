"""
Writing a bag: Jazzy's version 9 MCAP, atomically (a temporary name, then one rename).

Samples are written as one ``std_msgs/msg/Float64`` message per sample and channel, or as
batched ``Float64MultiArray`` messages (:mod:`dcmotor_id.formats.batch`), with rosbags'
serializer.
"""

from __future__ import annotations

from collections.abc import Mapping
import os
import shutil
from typing import Any, Optional

import numpy as np

from dcmotor_id.core.records import PathLike
from dcmotor_id.formats.bag.messages import BAG_TOPICS, FLOAT64_TYPE, jazzy_typestore
from dcmotor_id.formats.batch import batch_message, BATCH_TYPE, BatchTypes


#: Prefix of the staging directory of a bag being written (removed by the window writer).
PARTIAL_PREFIX = '.partial_'


def _batch_types(typestore: Any) -> BatchTypes:
    return BatchTypes(message=typestore.types[BATCH_TYPE],
                      layout=typestore.types['std_msgs/msg/MultiArrayLayout'],
                      dimension=typestore.types['std_msgs/msg/MultiArrayDimension'])


def write_bag(path: PathLike, stamps_ns: np.ndarray, channels: Mapping[str, np.ndarray],
              topics: Optional[Mapping[str, str]] = None, batch_samples: int = 0) -> int:
    """
    Write samples as a rosbag2 bag with MCAP storage (Jazzy's version 9), atomically.

    The bag is written under a temporary name next to ``path`` and renamed when complete, so
    ``path`` is either absent or a finished, readable bag, even if the process is killed.

    Parameters
    ----------
    path : str
        Bag directory to create (must not exist).
    stamps_ns : array_like of int
        Timestamp of every sample [ns] (the message timestamps).
    channels : dict
        ``voltage``, ``current``, ``speed`` -> arrays (voltage may be absent).
    topics : dict, optional
        Channel -> topic name written (default ``/voltage``, ``/current``, ``/speed``,
        ``/samples``).
    batch_samples : int
        0: one Float64 message per sample and channel; N > 0: Float64MultiArray messages of N
        samples on the samples topic (see :mod:`dcmotor_id.formats.batch`).

    Returns
    -------
    int
        Bytes written.

    """
    names = {channel: '/' + topic.lstrip('/') for channel, topic in BAG_TOPICS.items()}
    names.update(topics or {})
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    path = os.path.abspath(str(path))
    if os.path.exists(path):
        raise FileExistsError(f'{path} exists already; bags are never overwritten')
    parent, name = os.path.split(path)
    os.makedirs(parent, exist_ok=True)
    # the bag is built as <parent>/.partial_<name>/<name> so that its files carry their
    # final names, then moved up in one rename
    staging = os.path.join(parent, PARTIAL_PREFIX + name)
    if os.path.exists(staging):
        shutil.rmtree(staging)
    os.makedirs(staging)
    temporary = os.path.join(staging, name)
    try:
        _write_messages(temporary, names, stamps, channels, batch_samples)
        _fsync_tree(temporary)
        os.rename(temporary, path)
        _fsync_dir(parent)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return bag_size(path)


def _write_messages(temporary: str, names: Mapping[str, str], stamps: np.ndarray,
                    channels: Mapping[str, np.ndarray], batch_samples: int) -> None:
    """Write the bag's messages (Float64 per sample, or batches) at ``temporary``."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    typestore = jazzy_typestore()
    writer = Writer(temporary, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    try:
        if batch_samples > 0:
            _write_batches(writer, typestore, names['samples'], stamps, channels,
                           int(batch_samples))
        else:
            _write_float64(writer, typestore, names, stamps, channels)
    finally:
        writer.close()


def _write_float64(writer: Any, typestore: Any, names: Mapping[str, str], stamps: np.ndarray,
                   channels: Mapping[str, np.ndarray]) -> None:
    ordered = [channel for channel in ('voltage', 'current', 'speed') if channel in channels]
    connections = [writer.add_connection(names[channel], FLOAT64_TYPE, typestore=typestore)
                   for channel in ordered]
    # rosbags' serializer, not a hand-written CDR encoder (see bench/cdr_results.md)
    message = typestore.types[FLOAT64_TYPE]
    values = [np.asarray(channels[channel], dtype=float).tolist() for channel in ordered]
    for row, stamp in enumerate(stamps.tolist()):
        for connection, column in zip(connections, values):
            writer.write(connection, stamp,
                         typestore.serialize_cdr(message(data=column[row]), FLOAT64_TYPE))


def _write_batches(writer: Any, typestore: Any, topic: str, stamps: np.ndarray,
                   channels: Mapping[str, np.ndarray], batch_samples: int) -> None:
    types = _batch_types(typestore)
    connection = writer.add_connection(topic, BATCH_TYPE, typestore=typestore)
    nan = np.full(stamps.size, np.nan)
    for start in range(0, stamps.size, batch_samples):
        part = slice(start, min(start + batch_samples, stamps.size))
        time_s = (stamps[part] - stamps[part.start]).astype(float) * 1e-9
        message = batch_message(types, time_s, channels.get('voltage', nan)[part],
                                channels['current'][part], channels['speed'][part])
        writer.write(connection, int(stamps[part.start]),
                     typestore.serialize_cdr(message, BATCH_TYPE))


def _fsync_tree(path: str) -> None:
    for name in os.listdir(path):
        descriptor = os.open(os.path.join(path, name), os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)
    _fsync_dir(path)


def _fsync_dir(path: str) -> None:
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def bag_size(path: PathLike) -> int:
    """Bytes used by the files of a bag directory."""
    return sum(entry.stat().st_size for entry in os.scandir(path) if entry.is_file())
