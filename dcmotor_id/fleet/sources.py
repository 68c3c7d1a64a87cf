"""
Finding the recordings of a fleet and telling which motor each stream belongs to.

:func:`find_sources` walks the given paths for rosbag2 bags (directories with
``metadata.yaml``, MCAP or sqlite3 storage) and the files of every registered format
(:func:`dcmotor_id.formats.file_suffixes`: bare ``.mcap`` / ``.db3`` bags, CSV, MATLAB
``.mat``, Parquet ``.parquet`` / ``.pq``).
:func:`motor_streams` groups the topics of one bag by motor: by default the topics' namespace
(``/robot7/left/voltage`` -> ``robot7/left``), else the bag's place in the directory tree or
a regular expression on its path.
"""

from __future__ import annotations

from dataclasses import dataclass
import os
import re
from typing import Iterable, Mapping, Optional

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.formats import detect_format, file_suffixes
from dcmotor_id.formats.bag import FLOAT64_TYPE, PARTIAL_PREFIX
from dcmotor_id.formats.batch import BATCH_TYPE
from dcmotor_id.formats.paths import check_input_path

#: Last name component of each stream of a motor, as the identifier node names them.
CHANNEL_TOPICS = ('voltage', 'current', 'speed')
#: Last name component of the batched samples topic.
SAMPLES_TOPIC = 'samples'
#: The ways ``--motor-from`` names a motor besides a pattern.
MOTOR_FROM = ('namespace', 'path')


@dataclass(frozen=True)
class Source:
    """
    One recording found on disk.

    Attributes
    ----------
    path : str
        Absolute path of the bag directory, ``.mcap``/``.db3`` file or CSV file (the key of
        the history: a path already there is skipped).
    root : str
        The argument it was found under (a directory), or its parent directory.
    kind : str
        Its format (:func:`dcmotor_id.formats.detect_format`): ``bag``, ``csv``, ``mat``,
        ``parquet``, ...

    """

    path: str
    root: str
    kind: str

    @property
    def relative_dir(self) -> str:
        """Directory of the recording relative to its root (``''`` when directly in it)."""
        parent = os.path.dirname(self.path)
        relative = os.path.relpath(parent, self.root)
        return '' if relative == '.' else relative.replace(os.sep, '/')


def _is_bag_dir(path: str) -> bool:
    return os.path.isfile(os.path.join(path, 'metadata.yaml'))


def find_sources(paths: Iterable[str]) -> list[Source]:
    """
    Find every recording under ``paths``, recursively, in a stable (sorted) order.

    A directory with ``metadata.yaml`` is a bag (not descended into); elsewhere a file whose
    ending a format claims (:func:`dcmotor_id.formats.file_suffixes`, any case: ``.mcap``,
    ``.db3``, ``.csv``, ``.mat``, ``.parquet``, ...) is a recording. Hidden directories and the
    staging directories of bags being written are skipped. A file given by name is taken
    whatever its ending.

    Raises
    ------
    InputDataError
        When a path does not exist.

    """
    found: dict[str, Source] = {}
    suffixes = file_suffixes()
    for given in paths:
        path = os.path.abspath(given)
        if not os.path.lexists(path):
            raise InputDataError(f'{given}: no such file or directory; give bag directories, '
                                 '.mcap, CSV, .mat or .parquet files, or directories '
                                 'holding them')
        check_input_path(given, directory=True)
        if os.path.isfile(path) or _is_bag_dir(path):
            found.setdefault(path, Source(path, os.path.dirname(path), detect_format(path)))
            continue
        for directory, subdirs, files in os.walk(path):
            subdirs[:] = sorted(name for name in subdirs if not name.startswith('.'))
            bags = [name for name in subdirs if _is_bag_dir(os.path.join(directory, name))]
            for name in bags:
                bag = os.path.join(directory, name)
                found.setdefault(bag, Source(bag, path, 'bag'))
            subdirs[:] = [name for name in subdirs
                          if name not in bags and not name.startswith(PARTIAL_PREFIX)]
            for name in sorted(files):
                if name.lower().endswith(suffixes) and not name.startswith('.'):
                    file_path = os.path.join(directory, name)
                    found.setdefault(file_path, Source(file_path, path,
                                                       detect_format(file_path)))
    return sorted(found.values(), key=lambda source: source.path)


def namespace_of(topic: str) -> str:
    """Return a topic's namespace without slashes: ``/robot7/left/voltage`` -> ``robot7/left``."""
    return '/'.join(part for part in topic.split('/')[:-1] if part)


def path_motor_id(source: Source) -> str:
    """
    Name a motor by where its recording lies.

    The recording's directory relative to the argument it was found under
    (``fleet/robot7/left/run_3.mcap`` under ``fleet`` -> ``robot7/left``); for a recording
    directly in that directory, or given by name, the directory's own name.
    """
    return source.relative_dir or os.path.basename(os.path.dirname(source.path)) or 'motor'


def pattern_motor_id(source: Source, pattern: str) -> str:
    """
    Name a motor by a regular expression searched in the recording's path.

    The motor is the group ``motor`` if the pattern has one, else its first group, else the
    whole match.

    Raises
    ------
    InputDataError
        When the pattern does not match the path.

    """
    match = re.search(pattern, source.path)
    if match is None:
        raise InputDataError(f'{source.path}: --motor-from pattern {pattern!r} does not match '
                             'the path; give a regular expression that does (its group '
                             '"motor" or first group names the motor)')
    if 'motor' in match.re.groupindex:
        return match.group('motor')
    return match.group(1) if match.re.groups else match.group(0)


def check_motor_from(motor_from: str) -> None:
    """
    Refuse a ``--motor-from`` that is neither a known way nor a valid regular expression.

    Raises
    ------
    InputDataError
        With what to give instead.

    """
    if motor_from in MOTOR_FROM:
        return
    try:
        re.compile(motor_from)
    except re.error as error:
        raise InputDataError(f'--motor-from: {motor_from!r} is neither namespace, path nor a '
                             f'valid regular expression ({error})') from None


def motor_streams(source: Source, topics: Mapping[str, str],
                  motor_from: str = 'namespace') -> dict[str, dict[str, str]]:
    """
    Group a bag's topics by motor.

    Parameters
    ----------
    source : Source
        The bag.
    topics : dict
        Topic -> message type, as the bag declares them.
    motor_from : str
        ``namespace`` (default): the topics' namespace names the motor (topics without one
        fall back to ``path``); ``path``: :func:`path_motor_id`; anything else is a regular
        expression for :func:`pattern_motor_id` (then the bag holds one motor).

    Returns
    -------
    dict
        Motor id -> channel -> topic (``voltage``, ``current``, ``speed``, ``samples``;
        absolute names, for :func:`dcmotor_id.formats.bag.read_bag`). A namespace counts as
        a motor when it has a batched samples topic, or Float64 current and speed.

    """
    groups: dict[str, dict[str, str]] = {}
    for topic, kind in topics.items():
        channel = topic.rsplit('/', 1)[-1]
        if (channel in CHANNEL_TOPICS and kind == FLOAT64_TYPE) or \
                (channel == SAMPLES_TOPIC and kind == BATCH_TYPE):
            groups.setdefault(namespace_of(topic), {})[channel] = topic
    motors = {space: channels for space, channels in groups.items()
              if SAMPLES_TOPIC in channels or {'current', 'speed'} <= set(channels)}
    named: dict[str, dict[str, str]] = {}
    for space, channels in sorted(motors.items()):
        if motor_from == 'namespace' and space:
            motor = space
        elif motor_from in MOTOR_FROM:
            motor = path_motor_id(source)
        else:
            motor = pattern_motor_id(source, motor_from)
        if motor in named:
            raise InputDataError(f'{source.path}: two groups of streams name motor {motor!r} '
                                 f'({", ".join(sorted(motors))}); use --motor-from namespace')
        # absolute names for every channel, so that no other namespace's topic is matched
        named[motor] = {channel: channels.get(channel, f'/{space}/{channel}'.replace('//', '/'))
                        for channel in CHANNEL_TOPICS + (SAMPLES_TOPIC,)}
    return named


def file_motor_id(source: Source, motor_from: str = 'namespace') -> str:
    """Name the motor of a recording without topics, not a bag (by path, or by the pattern)."""
    if motor_from in MOTOR_FROM:
        return path_motor_id(source)
    return pattern_motor_id(source, motor_from)


def describe_topics(topics: Mapping[str, str], limit: Optional[int] = 12) -> str:
    """List topics with their types for a message (at most ``limit``)."""
    items = [f'{topic} [{kind}]' for topic, kind in sorted(topics.items())]
    if limit is not None and len(items) > limit:
        items = items[:limit] + [f'... {len(items) - limit} more']
    return ', '.join(items) or 'no topics'
